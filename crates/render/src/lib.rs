//! Differentiable forward models for 3D Gaussians in X-ray CT: projection onto a detector and
//! voxelization, as Burn custom ops with hand-written backward kernels.
//!
//! This crate is a leaf: it consumes plain [`Camera`]s and Gaussian parameter tensors and knows
//! nothing about scenes. Geometry conventions: `docs/geometry.md`.

pub mod camera;

pub use camera::{Camera, Projection, Ray};
