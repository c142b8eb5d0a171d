//! The voxel projector: the Joseph forward projector with its exact adjoint, the voxel-driven
//! backprojector of FDK, and the field-of-view check. It serves both the simulation (material
//! path lengths through HU volumes) and the reconstruction methods.
//!
//! Conventions are the project's (`docs/geometry.md`): volumes `[z][y][x]` of μ in mm⁻¹,
//! projections `[view][row][col]` of line integrals. Memory: a projector call holds the volume
//! (4·N³ bytes) plus the projections (4·V·R·C bytes); the adjoint adds one volume per worker
//! thread.

mod backproject;
mod fov;
mod joseph;

pub use backproject::backproject_voxel;
pub use fov::{check_fov, seen_by_every_view, unseen_fraction};
pub use joseph::{Joseph, dot};
