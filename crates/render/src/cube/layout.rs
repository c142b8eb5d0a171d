//! The width of the prepared projection records, apart from the kernels' launch code so that
//! the op definitions (`crate::ops`, which need it for Fusion's output shapes) do not depend on
//! the module implementing them.

use super::{exact, project};
use crate::options::ProjectionMode;

/// Width of one Gaussian's record in this backend's prepared projection state for `mode`.
pub fn prepared_width(mode: ProjectionMode) -> usize {
    match mode {
        ProjectionMode::Affine => project::AFFINE_WIDTH,
        ProjectionMode::Exact => exact::EXACT_WIDTH,
    }
}
