//! GSC-Net: a Gaussian-wise spectral density curve network.
//!
//! Maps each Gaussian's common raw density u^(c) and the ordered spectral grid τ_1 < … < τ_M to a
//! raw density curve Δu [K, M] (paper Sec. III-D); channel m then uses u^(m) = u^(c) + Δu^(m)
//! and α^(m) = softplus(u^(m)). Also provides the curve regulariser L_curve and the
//! piecewise-linear query of unobserved channels (Sec. III-E). This crate is a leaf: it knows
//! nothing about scenes or rendering.
//!
//! ```no_run
//! use burn::tensor::{Device, Tensor};
//! use prism_gscnet::{CurveModelConfig, SpectralGrid};
//! # fn main() -> prism_gscnet::Result<()> {
//! let device = Device::flex().autodiff();
//! let grid = SpectralGrid::new(vec![0.0, 0.3, 1.0])?;
//! let model = CurveModelConfig::default().init(&grid, &device, 7)?;
//! let u_c = Tensor::<1>::from_floats([-2.0, 0.5], &device);
//! let delta_u = model.forward(u_c, grid.to_tensor(&device))?; // [2, 3]
//! # Ok(()) }
//! ```

mod autodiff;
mod backend;
pub mod block;
pub mod composed;
pub mod config;
pub mod conv;
pub mod cpu;
pub mod curve;
pub mod error;
pub mod grid;
pub mod gscnet;
pub mod head;
pub(crate) mod init;
pub mod mlp;
pub mod model;
pub mod ops;
pub mod ssm;
pub mod tokenizer;

pub use config::{CurveModelConfig, CurveModelKind};
pub use curve::{Extrapolation, curve_regularizer, interpolate_curve};
pub use error::{Error, Result};
pub use grid::SpectralGrid;
pub use model::{CurveModel, CurveNet};

#[cfg(test)]
pub(crate) mod test_util {
    use burn::tensor::Device;

    /// The CPU test device: Flex (preferred; NdArray is deprecated in Burn 0.22) or NdArray
    /// when only the `ndarray` feature is enabled.
    #[cfg(feature = "flex")]
    pub fn cpu() -> Device {
        Device::flex()
    }

    #[cfg(all(feature = "ndarray", not(feature = "flex")))]
    #[allow(deprecated)]
    pub fn cpu() -> Device {
        Device::ndarray()
    }
}
