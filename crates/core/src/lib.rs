//! Prism's domain crate: scan geometry, spectral scenes and their file formats, X-ray physics,
//! phantoms, classic reconstructions, the Gaussian model and trainers, metrics.
//!
//! Conventions (axes, units, detector orientation) are written once in `docs/geometry.md` and
//! implemented once in [`geometry`].

pub mod classic;
pub mod error;
pub mod gaussian;
pub mod geometry;
pub mod method;
pub mod metrics;
pub mod phantom;
pub mod physics;
pub mod progress;
pub mod report;
pub mod scene;
pub mod simulate;
pub mod yaml;

pub use error::{Error, Result};
