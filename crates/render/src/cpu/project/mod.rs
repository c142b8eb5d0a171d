//! Projection of Gaussians onto the detector of each view: forward and backward.
//!
//! Per view, every Gaussian is prepared once in f64 ([`gm::splat_masked`], four Gaussians at a
//! time in lanes, or [`gm::exact_splat`]) into a pixel box; the prepared geometry is shared by all M density channels. A pixel receives a
//! Gaussian iff it lies within the Mahalanobis cut-off (affine: of the 2D footprint; exact: of
//! the ray's closest approach) — a relative criterion, unlike upstream's absolute `ρμG < 1e-5`
//! skip, so densities of 1e-8 still render.
//!
//! The affine preparation (f32 pixel splats, [`project_prepare`]) can be computed once and read
//! by both passes ([`project_forward_prepared`], [`project_backward_prepared`]); the Burn ops do
//! so. Both passes walk a Gaussian's box row by row in 8-lane blocks ([`super::lanes`],
//! AVX2+FMA when the CPU has it) that start at the box's own first column, so a footprint no
//! wider than a block is evaluated once per row. The forward pass bins Gaussians into bands of
//! [`BAND`] detector rows and owns one band per task (each pixel sums its Gaussians in index
//! order); the backward pass owns a group of four Gaussians per task: it sums each one's
//! image-space moments over its own pixels from the padded upstream gradient and chains the four
//! at once through [`gm::splat_backward_masked`] (one f64 splat per Gaussian, in lanes); the
//! exact backward accumulates per-pixel `∂/∂(centre, Σ⁻¹)` one Gaussian at a time.

mod backward;
mod forward;
mod prepare;
mod rows;

use backward::*;
use forward::*;
use prepare::*;
pub use prepare::{PREPARED_WIDTH, prepared_width, project_prepare};
use rows::*;

use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
use super::lanes::Avx2;
use super::lanes::{LANES, Lanes, Portable, RowBatches, UpstreamGrad, dispatched, drain, has_avx2};
use super::padded::PaddedRows;
use super::tiles::{Bins, TileBox, tile_span};
use super::{GaussianSlices, GradRow, grad_rows, zeros};
use crate::camera::Camera;
use crate::gaussian_math::{
    self as gm, ExactSplat, F64_LANES, F64x4, GaussianGeom, Real, SplatGrad, camera_ray,
    exact_splat, exact_splat_backward, line_integral_backward, ray_terms, sym_pack, sym_unpack,
};
use crate::options::{ProjectOptions, ProjectionMode};

/// Detector rows per forward task.
const BAND: usize = 8;

/// Gradients of a projection with respect to every input, row-major like the inputs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProjectGrads {
    pub means: Vec<f32>,
    pub scales: Vec<f32>,
    pub rotations: Vec<f32>,
    pub densities: Vec<f32>,
    /// `∂L/∂(screen offset)` per view and Gaussian, `[V, K, 2]` in pixels⁻¹: the projected-centre
    /// gradient that densification thresholds.
    pub screen: Vec<f32>,
}

/// Forward projection: image `[V, M, rows, cols]` of line integrals.
///
/// `screen` holds per-view screen offsets `[V, K, 2]` (pixels) added to the projected centres
/// (zeros in normal use; their gradient is the densification statistic). Every camera must have
/// the same detector size (checked by the caller).
pub fn project_forward(
    g: &GaussianSlices,
    screen: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    forward(g, screen, None, cams, opts)
}

/// [`project_forward`] reading the per-Gaussian preparation from `prepared` (made by
/// [`project_prepare`] from the same inputs). A buffer of the wrong length is ignored (the
/// preparation is then recomputed); boxes are clamped to the detector.
pub fn project_forward_prepared(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    forward(g, screen, fitting(prepared, g, cams), cams, opts)
}

/// `prepared` if it has the length [`project_prepare`] gives for `g` and `cams`.
fn fitting<'a>(prepared: &'a [f32], g: &GaussianSlices, cams: &[Camera]) -> Option<&'a [f32]> {
    (prepared.len() == cams.len() * g.len() * PREPARED_WIDTH).then_some(prepared)
}

/// Backward projection: gradients of `L` given `grad = ∂L/∂image` (`[V, M, rows, cols]`).
pub fn project_backward(
    g: &GaussianSlices,
    screen: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
    grad: &[f32],
) -> ProjectGrads {
    backward(g, screen, None, cams, opts, grad)
}

/// [`project_backward`] reading the per-Gaussian preparation from `prepared` (see
/// [`project_forward_prepared`]).
pub fn project_backward_prepared(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
    grad: &[f32],
) -> ProjectGrads {
    backward(g, screen, fitting(prepared, g, cams), cams, opts, grad)
}

/// Number of Gaussian–pixel evaluations one forward pass performs (affine: the pixels of each
/// footprint's cut-off rows; exact: every pixel of the footprint box; summed over views) — the
/// work unit of the benchmarks.
pub fn count_project_evaluations(
    g: &GaussianSlices,
    cams: &[Camera],
    opts: &ProjectOptions,
) -> usize {
    let screen = vec![0.0f32; 2 * g.len() * cams.len()];
    let mut total = 0;
    for (v, cam) in cams.iter().enumerate() {
        let prep = prepare(g, &screen, None, v, cam, opts);
        total += match prep {
            Prepared::Affine(splats) => {
                let cut2 = (opts.cutoff * opts.cutoff) as f32;
                let spans = |s: &PixelSplat| -> usize {
                    (s.y0..s.y1)
                        .filter_map(|y| {
                            row_span(s, y as f32 - s.my, cut2, s.x0 as usize, s.x1 as usize)
                        })
                        .map(|(a, b)| b - a)
                        .sum()
                };
                splats.iter().flatten().map(|s| spans(&s)).sum::<usize>()
            }
            Prepared::Exact(splats) => splats
                .iter()
                .flatten()
                .map(|(_, px)| (px[1] - px[0]) * (px[3] - px[2]))
                .sum(),
        };
    }
    total
}
