//! Neural attenuation fields (NAF, Zha et al., MICCAI 2022): a multiresolution hash-grid encoder
//! as a Burn custom op with a hand-written backward ([`ops::encode`]; CPU kernels in [`cpu`],
//! CubeCL kernels for wgpu), NAF's MLP as one op with a hand-written backward ([`ops::mlp`]; a
//! fused CPU kernel in [`mlp`], the backend's own tensor ops on wgpu), and the field module
//! that chains them ([`NeuralField`]). This crate is a leaf: it knows points in the unit cube,
//! not scans or rays.
//!
//! ```no_run
//! use burn::tensor::{Device, Tensor};
//! use prism_field::FieldConfig;
//! # fn main() -> prism_field::Result<()> {
//! let device = Device::flex().autodiff();
//! let field = FieldConfig::default().init(0, &device)?;
//! let points = Tensor::<2>::from_floats([[0.5, 0.5, 0.5], [0.1, 0.9, 0.3]], &device);
//! let mu = field.forward(points)?; // [2], in (0, 1)
//! # Ok(()) }
//! ```

mod autodiff;
mod backend;
pub mod cpu;
#[cfg(feature = "wgpu")]
mod cube;
pub mod error;
pub mod field;
pub mod grid;
pub mod mlp;
pub mod ops;

pub use error::{FieldError, Result};
pub use field::{FieldConfig, NeuralField};
pub use grid::{HashGrid, HashGridConfig};

#[cfg(test)]
mod tests;
