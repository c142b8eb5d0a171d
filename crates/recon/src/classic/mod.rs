//! Classic CT reconstruction, each channel independently: FDK/FBP (with Parker weights for short
//! scans) on the voxel-driven backprojector, the SART family (SART / OS-SART / SIRT) and CGLS on
//! the Joseph projector and its exact adjoint (`prism_domain::projector`), and ramp filters.
//!
//! Conventions are the project's (`docs/geometry.md`): volumes `[z][y][x]` of μ in mm⁻¹,
//! projections `[view][row][col]` of line integrals.

pub mod bench;
pub mod cgls;
pub mod config;
pub mod fdk;
pub mod filter;
pub mod sart;

pub use cgls::cgls;
pub use config::{ClassicConfig, ClassicMethod};
pub use fdk::{ScanKind, fdk, scan_kind};
pub use filter::{RampFilter, Window};
pub use sart::{Order, SartOptions, sart};

use crate::{Error, Result};
use ndarray::{Array3, ArrayView3, Axis};
use prism_domain::geometry::Geometry;
use prism_domain::projector::Joseph;
use rayon::prelude::*;

/// Reconstruct one channel's volume from the listed views (`views` index the scene geometry);
/// `progress` is called after each iteration of an iterative method.
pub fn reconstruct_channel(
    config: &ClassicConfig,
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    views: &[usize],
    progress: &mut dyn FnMut(usize),
) -> Result<Array3<f32>> {
    config.validate()?;
    if views.is_empty() {
        return Err(Error::invalid("views", "the view list is empty"));
    }
    let sub = geometry.with_views(views);
    let p = projections.select(Axis(0), views);
    match config.method {
        ClassicMethod::Fdk => fdk(&sub, p.view(), config.filter),
        ClassicMethod::Sart => sart(
            &Joseph::new(&sub)?,
            p.view(),
            None,
            &config.sart_options(),
            progress,
        ),
        ClassicMethod::Cgls => cgls(
            &Joseph::new(&sub)?,
            p.view(),
            None,
            config.resolved_iterations(),
            progress,
        ),
    }
}

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
mod iterative_tests;
