//! The classic reconstruction algorithms, as operators on one channel's projections: FDK/FBP
//! (with Parker weights for short scans) on the voxel-driven backprojector, the SART family
//! (SART / OS-SART / SIRT) and CGLS on the Joseph projector and its exact adjoint
//! (`prism_domain::projector`), total-variation regularised least squares over one or several
//! coupled channels (PDHG, [`tv`]) with its gradient operator, directional TV's guide ([`guide`]) and
//! total nuclear variation's 3 × 3 linear algebra (`nuclear`), and ramp filters. The classic methods
//! ([`crate::methods::classic`]) run them per channel; FDK also initialises the Gaussians and
//! NAF ([`crate::init`]).
//!
//! Conventions are the project's (`docs/geometry.md`): volumes `[z][y][x]` of μ in mm⁻¹,
//! projections `[view][row][col]` of line integrals.

pub mod axis;
pub mod cgls;
pub mod fdk;
pub mod filter;
pub mod gradient;
pub mod guide;
mod nuclear;
pub mod sart;
pub mod tv;

pub use cgls::cgls;
pub use fdk::{ScanKind, fdk, scan_kind};
pub use filter::{RampFilter, Window};
pub use guide::Directions;
pub use sart::{Order, SartOptions, sart};
pub use tv::{ChannelData, Coupling, TvOptions, Weighting, tv, tv_guided};

use ndarray::Array3;
use rayon::prelude::*;

/// `a[i] = f(a[i], b[i])` in parallel, for equally shaped standard-layout arrays.
pub(crate) fn par_zip(a: &mut Array3<f32>, b: &Array3<f32>, f: impl Fn(f32, f32) -> f32 + Sync) {
    let b = b.as_slice().expect("standard layout");
    a.as_slice_mut()
        .expect("standard layout")
        .par_iter_mut()
        .zip(b.par_iter())
        .for_each(|(x, &y)| *x = f(*x, y));
}

#[cfg(test)]
mod axis_tests;
#[cfg(test)]
mod iterative_tests;
#[cfg(test)]
mod tv_tests;
