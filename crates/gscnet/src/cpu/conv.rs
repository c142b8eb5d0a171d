//! The depthwise convolution over the spectral axis followed by SiLU, and its adjoint.
//!
//! Layouts (row-major, f32): input `u` and output `[K, M, E]`, weight `w` `[E, J]` (J odd, the
//! taps of a centred kernel), bias `[E]`. With r = (J − 1)/2 and zero padding:
//!
//! ```text
//! p_{k,m,e} = bias_e + Σ_j w_{e,j} u_{k, m+j−r, e}      (terms with m+j−r ∉ [0, M) vanish)
//! y         = SiLU(p) = p σ(p)
//! ```
//!
//! This is exactly Burn's `Conv1d` with `groups = E`, stride 1, dilation 1 and padding r on the
//! `[K, E, M]` transpose, fused with the activation and without the transposes.

use rayon::prelude::*;

use super::math::{self, MulAdd};
use super::{BLOCK, has_avx2, sum_partials};

/// Sizes: K Gaussians, M channels, E features, J taps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvDims {
    pub k: usize,
    pub m: usize,
    pub e: usize,
    pub j: usize,
}

/// Gradients of ⟨ḡ, SiLU(conv(u))⟩ with respect to `u`, `w` and `bias`.
#[derive(Debug, Clone)]
pub struct ConvGrads {
    pub u: Vec<f32>,
    pub w: Vec<f32>,
    pub bias: Vec<f32>,
}

fn check(dims: ConvDims, u: &[f32], w: &[f32], bias: &[f32]) {
    let ConvDims { k, m, e, j } = dims;
    assert_eq!(u.len(), k * m * e, "spectral conv: input length");
    assert_eq!(w.len(), e * j, "spectral conv: weight length");
    assert_eq!(bias.len(), e, "spectral conv: bias length");
    assert!(
        j % 2 == 1,
        "spectral conv: the kernel must have an odd number of taps"
    );
}

/// The weights tap-major, `[J, E]` (from `[E, J]`), so the kernels' loops over features read
/// them contiguously.
fn taps_major(w: &[f32], e: usize, j: usize) -> Vec<f32> {
    let mut wt = vec![0.0f32; e * j];
    for (ei, row) in w.chunks_exact(j.max(1)).enumerate() {
        for (tap, &v) in row.iter().enumerate() {
            wt[tap * e + ei] = v;
        }
    }
    wt
}

/// Pre-activations p `[M, E]` of one Gaussian's tile `u` `[M, E]` (weights `wt` `[J, E]`).
#[inline(always)]
fn pre_activation(dims: ConvDims, u: &[f32], wt: &[f32], bias: &[f32], p: &mut [f32]) {
    let ConvDims { m, e, j, .. } = dims;
    let r = j / 2;
    for mi in 0..m {
        let out = &mut p[mi * e..(mi + 1) * e];
        out.copy_from_slice(bias);
        for tap in 0..j {
            // Source row mi + tap − r, skipped outside [0, M).
            let Some(src) = (mi + tap).checked_sub(r).filter(|&s| s < m) else {
                continue;
            };
            let row = &u[src * e..(src + 1) * e];
            let w = &wt[tap * e..(tap + 1) * e];
            for ((o, &w), &u) in out.iter_mut().zip(w).zip(row) {
                *o += w * u;
            }
        }
    }
}

/// SiLU(conv(u)) of the Gaussians of one rayon block (`us`, `ys` `[count, M, E]`).
#[inline(always)]
fn forward_block<F: MulAdd>(dims: ConvDims, us: &[f32], wt: &[f32], bias: &[f32], ys: &mut [f32]) {
    let me = dims.m * dims.e;
    for (yk, uk) in ys.chunks_mut(me).zip(us.chunks(me)) {
        pre_activation(dims, uk, wt, bias, yk);
        for v in yk.iter_mut() {
            *v *= math::sigmoid::<F>(*v);
        }
    }
}

dispatched! {
    /// [`forward_block`], with AVX2 and FMA when `wide`.
    fn forward_block_on => forward_block(
        dims: ConvDims,
        us: &[f32],
        wt: &[f32],
        bias: &[f32],
        ys: &mut [f32],
    )
}

/// y = SiLU(conv(u)), `[K, M, E]`.
pub fn conv_silu_forward(dims: ConvDims, u: &[f32], w: &[f32], bias: &[f32]) -> Vec<f32> {
    conv_silu_forward_on(dims, u, w, bias, has_avx2())
}

/// [`conv_silu_forward`] on the AVX2 path (`wide`, only when the CPU has it) or the portable one.
fn conv_silu_forward_on(
    dims: ConvDims,
    u: &[f32],
    w: &[f32],
    bias: &[f32],
    wide: bool,
) -> Vec<f32> {
    check(dims, u, w, bias);
    let me = dims.m * dims.e;
    let mut y = vec![0.0f32; u.len()];
    if me == 0 {
        return y;
    }
    let wt = taps_major(w, dims.e, dims.j);
    y.par_chunks_mut(BLOCK * me)
        .zip(u.par_chunks(BLOCK * me))
        .for_each(|(ys, us)| forward_block_on(wide, dims, us, &wt, bias, ys));
    y
}

/// Adjoint of the Gaussians of one rayon block: writes their ∂u (`gus`, zeroed on entry) and
/// returns the block's partial sums of ∂w `[E, J]` and ∂bias `[E]`.
#[inline(always)]
fn backward_block<F: MulAdd>(
    dims: ConvDims,
    (us, gys): (&[f32], &[f32]),
    wt: &[f32],
    bias: &[f32],
    gus: &mut [f32],
) -> (Vec<f32>, Vec<f32>) {
    let ConvDims { m, e, j, .. } = dims;
    let me = m * e;
    let r = j / 2;
    let mut gwt = vec![0.0f32; j * e];
    let mut gbias = vec![0.0f32; e];
    let mut gp = vec![0.0f32; me];
    for ((guk, uk), gyk) in gus.chunks_mut(me).zip(us.chunks(me)).zip(gys.chunks(me)) {
        // ∂L/∂p = ḡ · SiLU'(p), SiLU'(p) = σ(p)(1 + p(1 − σ(p))).
        pre_activation(dims, uk, wt, bias, &mut gp);
        for (g, &gyv) in gp.iter_mut().zip(gyk) {
            let s = math::sigmoid::<F>(*g);
            *g = gyv * s * (1.0 + *g * (1.0 - s));
        }
        for mi in 0..m {
            let gprow = &gp[mi * e..(mi + 1) * e];
            for (gb, g) in gbias.iter_mut().zip(gprow) {
                *gb += g;
            }
            for tap in 0..j {
                let Some(src) = (mi + tap).checked_sub(r).filter(|&s| s < m) else {
                    continue;
                };
                let urow = &uk[src * e..(src + 1) * e];
                let gurow = &mut guk[src * e..(src + 1) * e];
                let w = &wt[tap * e..(tap + 1) * e];
                let gw = &mut gwt[tap * e..(tap + 1) * e];
                for ((((gu, gw), &w), &g), &u) in
                    gurow.iter_mut().zip(gw).zip(w).zip(gprow).zip(urow)
                {
                    *gu += w * g;
                    *gw += g * u;
                }
            }
        }
    }
    (gwt, gbias)
}

dispatched! {
    /// [`backward_block`], with AVX2 and FMA when `wide`.
    fn backward_block_on => backward_block(
        dims: ConvDims,
        ugy: (&[f32], &[f32]),
        wt: &[f32],
        bias: &[f32],
        gus: &mut [f32],
    ) -> (Vec<f32>, Vec<f32>)
}

/// Gradients of ⟨`gy`, SiLU(conv(u))⟩ (`gy` `[K, M, E]`).
pub fn conv_silu_backward(
    dims: ConvDims,
    u: &[f32],
    w: &[f32],
    bias: &[f32],
    gy: &[f32],
) -> ConvGrads {
    conv_silu_backward_on(dims, (u, gy), w, bias, has_avx2())
}

/// [`conv_silu_backward`] on the AVX2 path (`wide`, only when the CPU has it) or the portable one.
fn conv_silu_backward_on(
    dims: ConvDims,
    (u, gy): (&[f32], &[f32]),
    w: &[f32],
    bias: &[f32],
    wide: bool,
) -> ConvGrads {
    check(dims, u, w, bias);
    assert_eq!(gy.len(), u.len(), "spectral conv: output gradient length");
    let ConvDims { e, j, .. } = dims;
    let me = dims.m * e;
    let mut gu = vec![0.0f32; u.len()];
    let wt = taps_major(w, e, j);
    let mut partials: Vec<(Vec<f32>, Vec<f32>)> = Vec::new();
    if me > 0 {
        partials = gu
            .par_chunks_mut(BLOCK * me)
            .zip(u.par_chunks(BLOCK * me))
            .zip(gy.par_chunks(BLOCK * me))
            .map(|((gus, us), gys)| backward_block_on(wide, dims, (us, gys), &wt, bias, gus))
            .collect();
    }
    let (gwt, gbias): (Vec<_>, Vec<_>) = partials.into_iter().unzip();
    // ∂w `[J, E]` back to `[E, J]`.
    let gwt = sum_partials(gwt, j * e);
    let mut gw = vec![0.0f32; e * j];
    for (i, g) in gw.iter_mut().enumerate() {
        *g = gwt[(i % j) * e + i / j];
    }
    ConvGrads {
        u: gu,
        w: gw,
        bias: sum_partials(gbias, e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::SeedStream;

    /// The AVX2 build and the portable one differ only in σ's exp (fused vs unfused Horner
    /// steps, ≲ 1.5e-7 relative; Rust does not reassociate or contract the plain sums). SiLU'(p)
    /// = σ(1 + p(1 − σ)) turns that into an absolute error of about |p| ε in the derivative (the
    /// subtraction 1 − σ), and ∂u sums such terms with cancellation, so outputs and gradients are
    /// compared to 1e-5 of the larger of the value and 1 % of the array's largest magnitude.
    #[test]
    fn avx2_and_portable_paths_agree() {
        if !has_avx2() {
            println!("note: this CPU lacks AVX2/FMA; only the portable conv path exists here");
            return;
        }
        let dims = ConvDims {
            k: BLOCK + 5,
            m: 5,
            e: 7,
            j: 3,
        };
        let ConvDims { k, m, e, j } = dims;
        let mut rng = SeedStream::new(23);
        let mut sample =
            |n: usize| -> Vec<f32> { (0..n).map(|_| rng.range(-3.0, 3.0) as f32).collect() };
        let (u, w, bias, gy) = (
            sample(k * m * e),
            sample(e * j),
            sample(e),
            sample(k * m * e),
        );
        let close = |wide: &[f32], portable: &[f32], what: &str| {
            let scale = portable.iter().fold(0.0f32, |a, v| a.max(v.abs()));
            assert!(scale > 0.0, "{what}: all zero");
            for (a, b) in wide.iter().zip(portable) {
                let rel = (a - b).abs() / b.abs().max(0.01 * scale);
                assert!(rel <= 1e-5, "{what}: {a} vs {b}");
            }
        };
        close(
            &conv_silu_forward_on(dims, &u, &w, &bias, true),
            &conv_silu_forward_on(dims, &u, &w, &bias, false),
            "y",
        );
        let gw = conv_silu_backward_on(dims, (&u, &gy), &w, &bias, true);
        let gp = conv_silu_backward_on(dims, (&u, &gy), &w, &bias, false);
        close(&gw.u, &gp.u, "∂u");
        close(&gw.w, &gp.w, "∂w");
        close(&gw.bias, &gp.bias, "∂bias");
    }
}
