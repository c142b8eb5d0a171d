//! Differentiable forward models for 3D Gaussians in X-ray CT: projection onto a detector and
//! voxelization, as Burn custom ops with hand-written backward kernels.
//!
//! This crate is a leaf: it consumes plain [`Camera`]s and Gaussian parameter tensors and knows
//! nothing about scenes. Geometry conventions: `docs/geometry.md`.
//!
//! * [`project`]: Gaussians → `[V, M, rows, cols]` line integrals (affine splatting or the exact
//!   per-ray closed form, [`ProjectionMode`]), cone and parallel beam, several views and density
//!   channels per call; [`screen_probe`] / [`screen_grad_norm`] give the densification statistic.
//! * [`voxelize`]: Gaussians → `[M, nz, ny, nx]` density on any [`VoxelGrid`].
//! * [`gaussian_math`]: the per-Gaussian and per-ray math shared by forward and backward;
//!   [`cpu`]: the rayon kernels used by the NdArray and Flex backends; `cube` (feature
//!   `wgpu`): the CubeCL kernels of the wgpu backend.

// Index loops mirror the matrix math (and the CubeCL kernels that port it).
#![allow(clippy::needless_range_loop)]
// Without a backend feature the crate serves its plain types only (the options, the per-Gaussian
// math): the op registrations are then unused.
#![cfg_attr(
    not(any(feature = "flex", feature = "ndarray", feature = "wgpu")),
    allow(unused)
)]

mod autodiff;
mod backend;
pub mod cpu;
#[cfg(feature = "wgpu")]
pub mod cube;
pub mod error;
pub mod gaussian_math;
pub mod ops;
pub mod options;

pub use error::{RenderError, Result};
pub use ops::{
    GaussianOps, Gaussians, is_gpu, project, screen_grad_norm, screen_probe, validate_cameras,
    voxelize,
};
pub use options::{ProjectOptions, ProjectionMode, VoxelGrid, VoxelizeOptions};
/// The camera types, from the Burn-free `prism-camera` (`crate::camera::Camera` as before).
pub use prism_camera as camera;
pub use prism_camera::{Camera, Projection, Ray};
