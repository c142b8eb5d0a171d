//! 3D Gaussian models of attenuation and their trainers: R²-Gaussian per channel and 4D-SG
//! stage 1 (shared geometry).
//!
//! Data flow: FDK of the training views → [`init::from_fdk`] (host Gaussians) →
//! [`model::GaussianModel`] (raw tensors + Adam state on a Burn device) →
//! [`trainer::train`] (render with `prism-render`, loss, backward, Adam, densify) →
//! voxelized volumes, `log.jsonl`, safetensors / PLY ([`io`]). [`run::run`] wires this into
//! `prism recon` for `method: r2gs | 4dsg-stage1`.
//!
//! Units: the model lives in the normalised [`World`] (largest volume edge = 2, densities in
//! units of the FDK's 99.9th percentile); outputs are converted back to mm and mm⁻¹.

pub mod ablation;
pub mod adam;
pub mod checkpoint;
pub mod config;
pub mod densify;
pub mod host;
pub mod init;
pub mod io;
pub mod log;
pub mod loss;
pub mod model;
pub mod query;
pub mod run;
pub mod trainer;
pub mod world;

pub use config::{DeviceChoice, GaussianConfig, GaussianMethod};
pub use host::{HostGaussians, ScaleBounds};
pub use model::{GaussianModel, Learnable};
pub use world::World;

use burn::tensor::{Device, Tensor, TensorData};

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

/// The default CPU device: Flex (NdArray is deprecated in Burn 0.22) when compiled in.
pub fn cpu_device() -> burn::tensor::Device {
    #[cfg(feature = "flex")]
    {
        burn::tensor::Device::flex()
    }
    #[cfg(all(not(feature = "flex"), feature = "ndarray"))]
    {
        burn::tensor::Device::ndarray()
    }
}

#[cfg(test)]
pub(crate) fn test_device() -> burn::tensor::Device {
    cpu_device()
}

#[cfg(test)]
mod tests;
