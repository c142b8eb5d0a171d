//! Element-wise activations ([`Activation`]) and their adjoints, over a tensor of any shape:
//! GSC-Net's SiLU and the Gaussians' density softplus and bounded scale sigmoid.
//!
//! ```text
//! silu:      y = x σ(x)               ∂x = ḡ σ(x) (1 + x (1 − σ(x)))
//! softplus:  y = ln(1 + eˣ)           ∂x = ḡ σ(x)
//! sigmoid:   y = σ(x) span + lo       ∂x = ḡ span σ(x) (1 − σ(x)) = ḡ span e / (1 + e)², e = e^{−|x|}
//! ```
//!
//! One pass each way on [`math`]'s branch-free exp, softplus and sigmoid (so the loops vectorise;
//! AVX2 + FMA where the CPU has them), rayon over [`CHUNK`]-element pieces. Burn's composed forms
//! (its sigmoid is `exp(−log1p(exp(−x)))`, softplus five element-wise ops) take a pass per op and
//! as many again backward, each single-threaded on the CPU backends.

use rayon::prelude::*;

use super::has_avx2;
use super::math::{self, MulAdd};

/// An element-wise activation ([`crate::ops::activate`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    /// `x σ(x)`.
    Silu,
    /// `ln(1 + eˣ)`.
    Softplus,
    /// `σ(x)·span + lo` (a value in `(lo, lo + span)`).
    Sigmoid { lo: f32, span: f32 },
}

/// Elements per rayon task: a few microseconds of work, so scheduling stays negligible.
const CHUNK: usize = 16 * 1024;

#[inline(always)]
fn value<F: MulAdd>(kind: Activation, x: f32) -> f32 {
    match kind {
        Activation::Silu => x * math::sigmoid::<F>(x),
        Activation::Softplus => math::softplus::<F>(x),
        Activation::Sigmoid { lo, span } => math::sigmoid::<F>(x) * span + lo,
    }
}

#[inline(always)]
fn derivative<F: MulAdd>(kind: Activation, x: f32) -> f32 {
    match kind {
        Activation::Silu => {
            let s = math::sigmoid::<F>(x);
            s * F::mul_add(x, 1.0 - s, 1.0)
        }
        Activation::Softplus => math::sigmoid::<F>(x),
        // σ(1 − σ) = e / (1 + e)² with e = e^{−|x|}: no cancellation in 1 − σ.
        Activation::Sigmoid { span, .. } => {
            let e = math::exp::<F>(-x.abs());
            let d = 1.0 + e;
            span * (e / (d * d))
        }
    }
}

#[inline(always)]
fn forward_chunk<F: MulAdd>(kind: Activation, xs: &[f32], ys: &mut [f32]) {
    for (y, &x) in ys.iter_mut().zip(xs) {
        *y = value::<F>(kind, x);
    }
}

dispatched! {
    /// [`forward_chunk`], with AVX2 and FMA when `wide`.
    fn forward_chunk_on => forward_chunk(kind: Activation, xs: &[f32], ys: &mut [f32])
}

#[inline(always)]
fn backward_chunk<F: MulAdd>(kind: Activation, xs: &[f32], gs: &[f32], out: &mut [f32]) {
    for ((o, &x), &g) in out.iter_mut().zip(xs).zip(gs) {
        *o = g * derivative::<F>(kind, x);
    }
}

dispatched! {
    /// [`backward_chunk`], with AVX2 and FMA when `wide`.
    fn backward_chunk_on => backward_chunk(
        kind: Activation,
        xs: &[f32],
        gs: &[f32],
        out: &mut [f32],
    )
}

/// `kind` of every element.
pub fn forward(kind: Activation, x: &[f32]) -> Vec<f32> {
    forward_on(kind, x, has_avx2())
}

/// [`forward`] on the AVX2 path (`wide`, only when the CPU has it) or the portable one.
pub(crate) fn forward_on(kind: Activation, x: &[f32], wide: bool) -> Vec<f32> {
    let mut y = vec![0.0f32; x.len()];
    y.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK))
        .for_each(|(ys, xs)| forward_chunk_on(wide, kind, xs, ys));
    y
}

/// `∂L/∂x` given `grad = ∂L/∂y` (same length as `x`).
pub fn backward(kind: Activation, x: &[f32], grad: &[f32]) -> Vec<f32> {
    backward_on(kind, x, grad, has_avx2())
}

/// [`backward`] on the AVX2 path (`wide`) or the portable one.
pub(crate) fn backward_on(kind: Activation, x: &[f32], grad: &[f32], wide: bool) -> Vec<f32> {
    assert_eq!(x.len(), grad.len(), "activation backward: gradient length");
    let mut out = vec![0.0f32; x.len()];
    out.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK).zip(grad.par_chunks(CHUNK)))
        .for_each(|(os, (xs, gs))| backward_chunk_on(wide, kind, xs, gs, os));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const KINDS: [Activation; 3] = [
        Activation::Silu,
        Activation::Softplus,
        Activation::Sigmoid {
            lo: 0.0005,
            span: 0.4995,
        },
    ];

    /// f64 value and derivative.
    fn exact(kind: Activation, x: f32) -> (f64, f64) {
        let x = f64::from(x);
        let s = 1.0 / (1.0 + (-x).exp());
        // σ(1 − σ) without f64's own cancellation in 1 − σ.
        let e = (-x.abs()).exp();
        match kind {
            Activation::Silu => (x * s, s * (1.0 + x * (1.0 - s))),
            Activation::Softplus => (x.max(0.0) + e.ln_1p(), s),
            Activation::Sigmoid { lo, span } => {
                let (lo, span) = (f64::from(lo), f64::from(span));
                (s * span + lo, span * e / ((1.0 + e) * (1.0 + e)))
            }
        }
    }

    /// Values and derivatives against f64 over [−100, 100] (dense near 0, where σ turns), on
    /// both variants, across chunk boundaries. Bound: [`math`]'s exp is within 1.5e-7 relative
    /// (its ln and softplus within a few ulp), the few roundings after it add a few ulp, so 1e-6
    /// relative. Absolute floors: underflowed tails (exact values below 1e-36) 1e-30; SiLU's
    /// derivative crosses zero near x = −1.28 and rounds 1 − σ(x) to ½ ulp of 1, an error
    /// ≤ 3e-8·|x| (≤ 5e-7 where it still matters, x ≈ 16), so 1e-7 there.
    #[test]
    fn values_and_derivatives_match_f64() {
        let n = 3 * CHUNK + 17;
        let x: Vec<f32> = (0..n)
            .map(|i| {
                let t = i as f64 / (n - 1) as f64 * 2.0 - 1.0;
                (100.0 * t * t * t) as f32
            })
            .collect();
        let ones = vec![1.0f32; n];
        for kind in KINDS {
            let floor = if kind == Activation::Silu {
                1e-7
            } else {
                1e-30
            };
            for wide in [false, has_avx2()] {
                let y = forward_on(kind, &x, wide);
                let d = backward_on(kind, &x, &ones, wide);
                for i in 0..n {
                    let (ey, ed) = exact(kind, x[i]);
                    let (ty, td) = (1e-6 * ey.abs() + 1e-30, 1e-6 * ed.abs() + floor);
                    assert!(
                        (f64::from(y[i]) - ey).abs() <= ty,
                        "{kind:?} y({}) {} vs {ey}",
                        x[i],
                        y[i]
                    );
                    assert!(
                        (f64::from(d[i]) - ed).abs() <= td,
                        "{kind:?} y'({}) {} vs {ed}",
                        x[i],
                        d[i]
                    );
                }
            }
        }
    }

    /// The upstream gradient scales the derivative element by element; the tails stay finite
    /// (σ underflows to 0 below −88: SiLU y = −0, y' = −0; softplus(+∞) = +∞ aside).
    #[test]
    fn backward_scales_by_the_upstream_gradient_and_the_tails_are_finite() {
        let x = [f32::NEG_INFINITY, -1e4, -200.0, -0.5, 0.0, 0.5, 200.0, 1e4];
        let g = [2.0f32, 3.0, -2.0, 0.5, 4.0, -1.0, 2.0, 1.0];
        for kind in KINDS {
            let d1 = backward(kind, &x[1..], &[1.0; 7]);
            let dg = backward(kind, &x[1..], &g[1..]);
            for i in 0..7 {
                assert_eq!(dg[i], g[i + 1] * d1[i], "{kind:?} x = {}", x[i + 1]);
            }
            assert!(d1.iter().all(|v| v.is_finite()), "{kind:?}");
            if kind != Activation::Silu {
                // SiLU(−∞) = −∞·0 is NaN, as Burn's is.
                let edge = backward(kind, &x[..1], &[1.0]);
                assert!(edge[0].is_finite(), "{kind:?}");
                assert!(
                    forward(kind, &x[..7]).iter().all(|v| v.is_finite()),
                    "{kind:?}"
                );
            }
        }
        let (y, d) = (
            forward(Activation::Silu, &x[1..]),
            backward(Activation::Silu, &x[1..], &[1.0; 7]),
        );
        assert!(y.iter().all(|v| v.is_finite()));
        assert_eq!((y[0], y[6]), (0.0, 1e4));
        assert_eq!((d[0], d[6]), (0.0, 1.0));
        assert_eq!((y[3], d[3]), (0.0, 0.5));
        assert_eq!(
            forward(Activation::Softplus, &[f32::INFINITY])[0],
            f32::INFINITY
        );
    }
}
