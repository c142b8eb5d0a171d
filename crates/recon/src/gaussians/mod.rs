//! The Gaussian representation of attenuation: raw parameters on the host ([`host`]) and on a
//! Burn device with their Adam state ([`model`], [`adam`]), the normalised [`world`] they live
//! in, their voxelized volumes ([`volume`]), and their files ([`io`]: safetensors and PLY).
//!
//! Units: the model lives in the normalised [`World`] (largest volume edge = 2, densities in
//! units of the FDK's 99.9th percentile); volumes and files are converted back to mm and mm⁻¹.

pub mod adam;
pub mod config;
pub mod finish;
pub mod host;
pub mod io;
pub mod model;
pub mod state;
pub mod train;
pub mod volume;
pub mod world;

pub use config::{GeometryConfig, ProjectionConfig};
pub use host::{HostGaussians, ScaleBounds};
pub use model::{GaussianModel, Learnable};
pub use world::World;
