//! CPU kernels (rayon) shared by the NdArray and Flex backends: slices in, `Vec`s out.
//!
//! The projection bins Gaussians into detector tiles first (no per-pixel scan of all Gaussians).
//! Its forward pass owns one tile per task and sums its Gaussians in index order (no atomics, no
//! depth sort); its backward pass writes per-(tile, Gaussian) partial sums into disjoint slices,
//! then gathers them per Gaussian. The voxelizer bins Gaussians into z-slabs for its forward pass
//! and walks each Gaussian's own voxel box in its backward pass (`voxelize.rs`). There are no
//! shared writes anywhere.

mod lanes;
mod padded;
mod project;
mod tiles;
mod voxelize;

pub use project::{
    PREPARED_WIDTH, ProjectGrads, count_project_evaluations, prepared_width, project_backward,
    project_backward_prepared, project_forward, project_forward_prepared, project_prepare,
};
pub use tiles::{Bins, TileBox, tile_span};
pub use voxelize::{VoxelizeGrads, voxelize_backward, voxelize_forward};

use crate::gaussian_math::{GaussianGeom, GeomGrad};
use rayon::prelude::*;

pub use prism_kernel::simd::{Fused, MulAdd, Separate};

/// `exp(x)` for `x ≤ 0` in f32, branch-free and conversion-free so pixel rows vectorise:
/// `2ⁿ · e^y` with `n = round(x / ln 2)`, `|y| ≤ ln2 / 2` and a degree-6 Taylor polynomial
/// (truncation `|y|⁷/7! < 1.2e-7`). `n` is read from the bits of the rounding sum itself, so no
/// float→int conversion is needed. Arguments below −87 (and −∞) are clamped to −87 (result
/// ≈ 1.6e-38, where the value no longer matters); NaN propagates.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    exp_neg_with::<Separate>(x)
}

/// [`exp_neg`] with the multiply-adds of `F` (the fused variant differs in the last bits only).
#[inline(always)]
pub fn exp_neg_with<F: MulAdd>(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // Adding 1.5·2²³ rounds to the nearest integer (without SSE4.1) and leaves that integer in
    // the low mantissa bits: t.to_bits() − MAGIC.to_bits() = n.
    const MAGIC: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 0.0);
    let t = F::mul_add(x, LOG2E, MAGIC);
    let n = t - MAGIC;
    let ni = (t.to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32);
    let y = F::mul_add(-n, LN2_LO, F::mul_add(-n, LN2_HI, x));
    // Estrin's scheme: p = (1 + y) + y²(½ + y/6) + y⁴(1/24 + y/120 + y²/720), a dependency
    // chain of 3 multiply-adds after y² instead of Horner's 6 (the pixel kernels are
    // latency-bound).
    let y2 = y * y;
    let y4 = y2 * y2;
    let lo = F::mul_add(y2, F::mul_add(y, 1.0 / 6.0, 0.5), y + 1.0);
    let hi = F::mul_add(y2, 1.0 / 720.0, F::mul_add(y, 1.0 / 120.0, 1.0 / 24.0));
    let p = F::mul_add(y4, hi, lo);
    let scale = f32::from_bits(((ni + 127) as u32) << 23);
    p * scale
}

/// Borrowed Gaussian parameters, row-major: means `[K, 3]`, scales `[K, 3]`, rotations `[K, 4]`
/// (`w, x, y, z`), densities `[K, M]` (M channels sharing one geometry).
#[derive(Clone, Copy, Debug)]
pub struct GaussianSlices<'a> {
    pub means: &'a [f32],
    pub scales: &'a [f32],
    pub rotations: &'a [f32],
    pub densities: &'a [f32],
    pub channels: usize,
}

impl GaussianSlices<'_> {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len() / 3
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[inline]
    pub fn geom(&self, i: usize) -> GaussianGeom {
        let m = &self.means[3 * i..3 * i + 3];
        let s = &self.scales[3 * i..3 * i + 3];
        let q = &self.rotations[4 * i..4 * i + 4];
        GaussianGeom {
            mean: [m[0] as f64, m[1] as f64, m[2] as f64],
            scale: [s[0] as f64, s[1] as f64, s[2] as f64],
            quat: [q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64],
        }
    }

    /// Densities of Gaussian `i`, or `None` if any is non-finite (the Gaussian is then skipped).
    #[inline]
    pub fn densities_of(&self, i: usize) -> Option<&[f32]> {
        let d = &self.densities[self.channels * i..self.channels * (i + 1)];
        d.iter().all(|v| v.is_finite()).then_some(d)
    }
}

/// A group of consecutive Gaussians' rows of the gradient buffers a backward pass writes:
/// mean (3), scale (3), rotation (4), densities (M) each.
pub(crate) struct GradRow<'a> {
    mean: &'a mut [f32],
    scale: &'a mut [f32],
    rotation: &'a mut [f32],
    densities: &'a mut [f32],
}

impl GradRow<'_> {
    /// Number of Gaussians in the group.
    pub(crate) fn len(&self) -> usize {
        self.mean.len() / 3
    }

    /// Add `geo` and the density gradients `scale · dens[c]` (f64, rounded to f32) to the group's
    /// `j`-th Gaussian, unless any of them is not finite (then its row is left as it is); whether
    /// they were added.
    pub(crate) fn add(&mut self, j: usize, geo: &GeomGrad, scale: f64, dens: &[f64]) -> bool {
        let finite = geo
            .mean
            .iter()
            .chain(&geo.scale)
            .chain(&geo.quat)
            .all(|x| x.is_finite())
            && dens.iter().all(|x| (scale * x).is_finite());
        if !finite {
            return false;
        }
        for q in 0..3 {
            self.mean[3 * j + q] += geo.mean[q] as f32;
            self.scale[3 * j + q] += geo.scale[q] as f32;
        }
        for q in 0..4 {
            self.rotation[4 * j + q] += geo.quat[q] as f32;
        }
        let m = dens.len();
        for (o, d) in self.densities[m * j..m * (j + 1)].iter_mut().zip(dens) {
            *o += (scale * d) as f32;
        }
        true
    }
}

/// The rows of a backward pass's gradient buffers (`[K, 3]`, `[K, 3]`, `[K, 4]`, `[K, m]`) in
/// groups of `per` consecutive Gaussians (the last group may be shorter), one task per group.
pub(crate) fn grad_rows<'a>(
    means: &'a mut [f32],
    scales: &'a mut [f32],
    rotations: &'a mut [f32],
    densities: &'a mut [f32],
    m: usize,
    per: usize,
) -> impl IndexedParallelIterator<Item = GradRow<'a>> {
    means
        .par_chunks_mut(3 * per)
        .zip(scales.par_chunks_mut(3 * per))
        .zip(rotations.par_chunks_mut(4 * per))
        .zip(densities.par_chunks_mut(m * per))
        .map(|(((mean, scale), rotation), densities)| GradRow {
            mean,
            scale,
            rotation,
            densities,
        })
}

/// Values per task of [`zeros`].
const ZERO_CHUNK: usize = 1 << 15;

/// `n` zeros, written by the worker pool in parallel: the allocator zeroes a buffer with one
/// `memset` on the calling thread, a serial pass over megabytes (every gradient buffer of a
/// backward pass) while the other workers wait.
pub(crate) fn zeros(n: usize) -> Vec<f32> {
    if n < 4 * ZERO_CHUNK {
        return vec![0.0; n];
    }
    let mut v = Vec::with_capacity(n);
    v.spare_capacity_mut()[..n]
        .par_chunks_mut(ZERO_CHUNK)
        .for_each(|c| c.fill(std::mem::MaybeUninit::new(0.0)));
    // SAFETY: the chunks cover slots 0..n (capacity ≥ n) and each was written.
    unsafe { v.set_len(n) };
    v
}

/// The gradient rows of Gaussian `i` alone (a group of one).
pub(crate) fn grad_row<'a>(
    means: &'a mut [f32],
    scales: &'a mut [f32],
    rotations: &'a mut [f32],
    densities: &'a mut [f32],
    m: usize,
    i: usize,
) -> GradRow<'a> {
    GradRow {
        mean: &mut means[3 * i..3 * i + 3],
        scale: &mut scales[3 * i..3 * i + 3],
        rotation: &mut rotations[4 * i..4 * i + 4],
        densities: &mut densities[m * i..m * i + m],
    }
}

#[cfg(test)]
pub(crate) mod tests;
