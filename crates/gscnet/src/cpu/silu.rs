//! SiLU, `y = x σ(x)`, and its adjoint, element-wise over a tensor of any shape.
//!
//! ```text
//! y  = x σ(x)
//! ∂x = ḡ σ(x) (1 + x (1 − σ(x)))
//! ```
//!
//! One pass each way, branch-free ([`math::sigmoid`]) so the loops vectorise, rayon over
//! [`CHUNK`]-element pieces. Burn's composed `silu` takes a sigmoid (itself
//! `exp(−log1p(exp(−x)))`) and a product, and its backward as many passes again, each
//! single-threaded on the CPU backends: for GSC-Net's gates and heads on a 2048-node table that was
//! the largest serial cost of a 4D-SG stage-2 step.

use rayon::prelude::*;

use super::has_avx2;
use super::math::{self, MulAdd};

/// Elements per rayon task: a few microseconds of work, so scheduling stays negligible.
const CHUNK: usize = 16 * 1024;

#[inline(always)]
fn forward_chunk<F: MulAdd>(xs: &[f32], ys: &mut [f32]) {
    for (y, &x) in ys.iter_mut().zip(xs) {
        *y = x * math::sigmoid::<F>(x);
    }
}

dispatched! {
    /// [`forward_chunk`], with AVX2 and FMA when `wide`.
    fn forward_chunk_on => forward_chunk(xs: &[f32], ys: &mut [f32])
}

#[inline(always)]
fn backward_chunk<F: MulAdd>(xs: &[f32], gs: &[f32], out: &mut [f32]) {
    for ((o, &x), &g) in out.iter_mut().zip(xs).zip(gs) {
        let s = math::sigmoid::<F>(x);
        *o = g * (s * F::mul_add(x, 1.0 - s, 1.0));
    }
}

dispatched! {
    /// [`backward_chunk`], with AVX2 and FMA when `wide`.
    fn backward_chunk_on => backward_chunk(xs: &[f32], gs: &[f32], out: &mut [f32])
}

/// `x σ(x)` of every element.
pub fn silu_forward(x: &[f32]) -> Vec<f32> {
    silu_forward_on(x, has_avx2())
}

/// [`silu_forward`] on the AVX2 path (`wide`, only when the CPU has it) or the portable one.
pub(crate) fn silu_forward_on(x: &[f32], wide: bool) -> Vec<f32> {
    let mut y = vec![0.0f32; x.len()];
    y.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK))
        .for_each(|(ys, xs)| forward_chunk_on(wide, xs, ys));
    y
}

/// `∂L/∂x` given `grad = ∂L/∂y` (same length as `x`).
pub fn silu_backward(x: &[f32], grad: &[f32]) -> Vec<f32> {
    silu_backward_on(x, grad, has_avx2())
}

/// [`silu_backward`] on the AVX2 path (`wide`) or the portable one.
pub(crate) fn silu_backward_on(x: &[f32], grad: &[f32], wide: bool) -> Vec<f32> {
    assert_eq!(x.len(), grad.len(), "silu backward: gradient length");
    let mut out = vec![0.0f32; x.len()];
    out.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK).zip(grad.par_chunks(CHUNK)))
        .for_each(|(os, (xs, gs))| backward_chunk_on(wide, xs, gs, os));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f64 SiLU and its derivative.
    fn exact(x: f32) -> (f64, f64) {
        let x = f64::from(x);
        let s = 1.0 / (1.0 + (-x).exp());
        (x * s, s * (1.0 + x * (1.0 - s)))
    }

    /// Values and derivatives against f64 over [−100, 100] (dense near 0, where σ turns), on
    /// both variants, across chunk boundaries. Bound: σ's exp is within 1.5e-7 relative, the
    /// product and the derivative's roundings add a few ulp, so 1e-6 relative. Absolute floors:
    /// the derivative crosses zero near x = −1.28 and rounds 1 − σ(x) to ½ ulp of 1, an error
    /// ≤ 3e-8·|x| (≤ 5e-7 where it still matters, x ≈ 16), so 1e-7 + 1e-6 relative; y underflows
    /// below x ≈ −88 (exact |y| < 1e-36).
    #[test]
    fn silu_and_its_derivative_match_f64() {
        let n = 3 * CHUNK + 17;
        let x: Vec<f32> = (0..n)
            .map(|i| {
                let t = i as f64 / (n - 1) as f64 * 2.0 - 1.0;
                (100.0 * t * t * t) as f32
            })
            .collect();
        let ones = vec![1.0f32; n];
        for wide in [false, has_avx2()] {
            let y = silu_forward_on(&x, wide);
            let d = silu_backward_on(&x, &ones, wide);
            for i in 0..n {
                let (ey, ed) = exact(x[i]);
                let ty = 1e-6 * ey.abs() + 1e-30;
                let td = 1e-6 * ed.abs() + 1e-7;
                assert!(
                    (f64::from(y[i]) - ey).abs() <= ty,
                    "y({}) {} vs {ey}",
                    x[i],
                    y[i]
                );
                assert!(
                    (f64::from(d[i]) - ed).abs() <= td,
                    "y'({}) {} vs {ed}",
                    x[i],
                    d[i]
                );
            }
        }
    }

    /// The upstream gradient scales the derivative element by element; the tails stay finite
    /// (σ underflows to 0 below −88: y = −0, y' = −0).
    #[test]
    fn backward_scales_by_the_upstream_gradient_and_the_tails_are_finite() {
        let x = [-1e4f32, -200.0, -0.5, 0.0, 0.5, 200.0, 1e4];
        let g = [3.0f32, -2.0, 0.5, 4.0, -1.0, 2.0, 1.0];
        let d1 = silu_backward(&x, &[1.0; 7]);
        let dg = silu_backward(&x, &g);
        for i in 0..x.len() {
            assert_eq!(dg[i], g[i] * d1[i], "x = {}", x[i]);
        }
        let y = silu_forward(&x);
        assert!(y.iter().chain(&d1).all(|v| v.is_finite()));
        assert_eq!((y[0], y[6]), (0.0, 1e4));
        assert_eq!((d1[0], d1[6]), (0.0, 1.0));
        assert_eq!((y[3], d1[3]), (0.0, 0.5));
    }
}
