//! Where a trained method runs: the configured [`DeviceChoice`], the Burn device it stands for,
//! and values moved between the host and a device ([`host_values`], [`upload`]).

use crate::Result;
use burn::tensor::{Device, Tensor, TensorData};
use serde::{Deserialize, Serialize};

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
    /// The Burn device, or an error if this build lacks the backend.
    pub fn device(self) -> Result<burn::tensor::Device> {
        match self {
            DeviceChoice::Cpu => Ok(cpu_device()),
            #[cfg(feature = "wgpu")]
            DeviceChoice::Wgpu => Ok(burn::tensor::Device::wgpu(
                burn::tensor::DeviceKind::DefaultDevice,
            )),
            #[cfg(not(feature = "wgpu"))]
            DeviceChoice::Wgpu => Err(crate::Error::invalid(
                "device",
                "wgpu needs a prism built with `--features wgpu`",
            )),
        }
    }
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
