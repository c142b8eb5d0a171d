//! Prism's domain: what a spectral CT scan is, independent of how it is reconstructed.
//!
//! Data flow: a scene config → [`simulate`] (a [`phantom`] or an HU volume → material paths
//! through the [`projector`] → [`physics`] channels → noise) → a [`scene::Scene`] (its directory
//! format in [`scene`]) → the reconstruction crate (`prism-recon`) → volumes scored by
//! [`metrics`]. Nothing here depends on a reconstruction method.
//!
//! Conventions (axes, units, detector orientation) are written once in `docs/geometry.md` and
//! implemented once in [`geometry`]. Long computations report progress through an
//! [`observe::Observer`]; this crate never prints.

pub mod decompose;
pub mod error;
pub mod export;
pub mod geometry;
pub mod import;
pub mod indices;
pub mod memory;
pub mod metrics;
pub mod observe;
pub mod phantom;
pub mod physics;
pub mod projector;
pub mod scene;
pub mod simulate;
pub mod staged;
#[cfg(any(test, feature = "testing"))]
pub mod testing;
pub mod yaml;

pub use error::{Error, Result};
