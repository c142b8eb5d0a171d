//! The Gaussian representation of attenuation: raw parameters on the host ([`host`]) and on a
//! Burn device with their Adam state ([`model`], [`adam`]), the normalised [`world`] they live
//! in, their voxelized volumes ([`volume`]), and their files ([`io`]: safetensors and PLY).
//!
//! Units: the model lives in the normalised [`World`] (largest volume edge = 2, densities in
//! units of the FDK's 99.9th percentile); volumes and files are converted back to mm and mm⁻¹.

pub mod adam;
pub mod config;
pub mod host;
pub mod io;
pub mod model;
pub mod state;
pub mod volume;
pub mod world;

pub use config::{DeviceChoice, GaussianConfig, GaussianMethod, ProjectionConfig};
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
