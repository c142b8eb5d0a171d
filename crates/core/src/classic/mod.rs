//! Classic CT reconstruction: the Joseph projector and its exact adjoint, the voxel-driven FDK
//! backprojector, ramp filters, FDK/FBP (with Parker weights for short scans), the SART family
//! (SART / OS-SART / SIRT) and CGLS, and a field-of-view check.
//!
//! Conventions are the project's (`docs/geometry.md`): volumes `[z][y][x]` of μ in mm⁻¹,
//! projections `[view][row][col]` of line integrals. Memory: a projector call holds the volume
//! (4·N³ bytes) plus the projections (4·V·R·C bytes); the adjoint adds one volume per worker
//! thread.

pub mod backproject;
pub mod bench;
pub mod cgls;
pub mod fdk;
pub mod filter;
pub mod fov;
pub mod joseph;
pub mod recon;
pub mod sart;

pub use backproject::backproject_voxel;
pub use cgls::cgls;
pub use fdk::{ScanKind, fdk, scan_kind};
pub use filter::{RampFilter, Window};
pub use fov::{check_fov, unseen_fraction};
pub use joseph::Joseph;
pub use sart::{Order, SartOptions, sart};

#[cfg(test)]
pub(crate) mod testutil;

#[cfg(test)]
mod iterative_tests;
