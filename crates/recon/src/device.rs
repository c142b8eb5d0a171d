//! Where a trained method runs: the configured [`DeviceChoice`], the Burn device it stands for,
//! values moved between the host and a device ([`host_values`], [`upload`]), and the CPU's
//! worker pool a run drives its kernels from ([`on_cpu_workers`]).

use crate::Result;
use burn::tensor::{Device, Tensor, TensorData};
use serde::{Deserialize, Serialize};

/// Run `f` on a worker of a new rayon pool of one thread per core (`RAYON_NUM_THREADS` if set),
/// with 8 MiB stacks (a main thread's size); `f` on the calling thread if the pool cannot be
/// built.
///
/// The thread that drives a training step then is itself a worker: a parallel kernel starts on
/// it while the other workers steal, instead of a thread outside the pool handing every kernel
/// over and sleeping until it ends (a wake-up per kernel, and one more thread than cores). Stage
/// 2 of the main job took 0.91× as long, bit for bit the same results (docs/benchmarks.md).
pub fn on_cpu_workers<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    match rayon::ThreadPoolBuilder::new().stack_size(8 << 20).build() {
        Ok(pool) => pool.install(f),
        Err(_) => f(),
    }
}

/// The compute device of a trained method (the Gaussian methods and NAF).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceChoice {
    /// Burn's Flex backend with Prism's rayon kernels.
    #[default]
    Cpu,
    /// Burn's wgpu backend with Prism's CubeCL kernels.
    Wgpu,
}

impl DeviceChoice {
    /// The Burn device, or an error if this build lacks the backend or (wgpu) no adapter comes up.
    pub fn device(self) -> Result<burn::tensor::Device> {
        match self {
            DeviceChoice::Cpu => Ok(cpu_device()),
            #[cfg(feature = "wgpu")]
            DeviceChoice::Wgpu => {
                let device = burn::tensor::Device::wgpu(burn::tensor::DeviceKind::DefaultDevice);
                wgpu_probe(&device)?;
                Ok(device)
            }
            #[cfg(not(feature = "wgpu"))]
            DeviceChoice::Wgpu => Err(crate::Error::invalid(
                "device",
                "wgpu needs a prism built with `--features wgpu`",
            )),
        }
    }
}

/// One value uploaded to the wgpu device and read back, once per process, so that a machine
/// without a usable adapter (no GPU, or a Vulkan driver whose ICD does not load) is an error saying
/// so rather than a panic inside the runtime (CubeCL acquires the adapter on a thread of its own
/// and panics there; the read then fails here). The runtime's message goes into the error.
#[cfg(feature = "wgpu")]
fn wgpu_probe(device: &Device) -> Result<()> {
    use std::sync::OnceLock;
    static PROBE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    let outcome = PROBE.get_or_init(|| {
        let one = || Tensor::<1>::from_data(TensorData::new(vec![1.0f32], [1]), device);
        match crate::error::catch_panics(|| host_values(&one())) {
            Ok(v) if v == [1.0] => Ok(()),
            Ok(v) => Err(format!("a value written as 1 read back as {v:?}")),
            Err(why) => Err(format!(
                "no usable GPU adapter ({})",
                why.unwrap_or_default()
            )),
        }
    });
    outcome.clone().map_err(|cause| {
        crate::Error::invalid(
            "device",
            format!(
                "wgpu: {cause}. The GPU needs a Vulkan driver whose ICD loads (VK_LOADER_DEBUG=error \
                 prints why the loader found none; the NVIDIA ICD also needs glvnd's \
                 libGLdispatch.so.0), or run with --device cpu"
            ),
        )
    })
}

/// The default CPU device: Flex when compiled in (NdArray is deprecated in Burn 0.22).
pub fn cpu_device() -> Device {
    #[cfg(feature = "flex")]
    {
        Device::flex()
    }
    #[cfg(all(not(feature = "flex"), feature = "ndarray"))]
    {
        #[allow(deprecated)]
        Device::ndarray()
    }
}

/// The values of a tensor, row-major, as f32 (one host read).
pub fn host_values<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    t.to_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("float tensors convert to f32")
}

/// A `[rows, cols]` tensor from row-major values.
pub fn upload(values: Vec<f32>, cols: usize, device: &Device) -> Tensor<2> {
    let rows = values.len() / cols.max(1);
    Tensor::from_data(TensorData::new(values, [rows, cols]), device)
}
