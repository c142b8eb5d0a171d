//! The activations of the Gaussians' raw parameters and their adjoints, element-wise on `&[f32]`
//! (rayon over [`CHUNK`]-element pieces; libm's `exp` and `ln_1p`, as Burn's own ops use).
//!
//! ```text
//! softplus:  y = max(x, 0) + ln(1 + e^{−|x|})     ∂x = ḡ σ(x)
//! sigmoid:   y = σ(x) span + lo                    ∂x = ḡ span σ(x) (1 − σ(x)) = ḡ span e / (1 + e)²
//! ```
//!
//! with σ(x) = 1 / (1 + e^{−x}) formed from `e = e^{−|x|}` (never overflowing): `1 / (1 + e)`
//! for x ≥ 0 and `e / (1 + e)` below.

use rayon::prelude::*;

use super::Activation;

/// Elements per rayon task.
const CHUNK: usize = 8 * 1024;

#[inline(always)]
fn logistic(x: f32) -> f32 {
    let e = (-x.abs()).exp();
    if x >= 0.0 {
        1.0 / (1.0 + e)
    } else {
        e / (1.0 + e)
    }
}

#[inline(always)]
fn forward_one(kind: Activation, x: f32) -> f32 {
    match kind {
        Activation::Softplus => x.max(0.0) + (-x.abs()).exp().ln_1p(),
        Activation::Sigmoid { lo, span } => logistic(x) * span + lo,
    }
}

#[inline(always)]
fn derivative(kind: Activation, x: f32) -> f32 {
    match kind {
        Activation::Softplus => logistic(x),
        // σ(1 − σ) = e / (1 + e)² with e = e^{−|x|}: no cancellation in 1 − σ.
        Activation::Sigmoid { span, .. } => {
            let e = (-x.abs()).exp();
            let d = 1.0 + e;
            span * (e / (d * d))
        }
    }
}

/// `kind` of every element of `x`.
pub fn forward(kind: Activation, x: &[f32]) -> Vec<f32> {
    let mut y = vec![0.0f32; x.len()];
    y.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK))
        .for_each(|(ys, xs)| {
            for (y, &x) in ys.iter_mut().zip(xs) {
                *y = forward_one(kind, x);
            }
        });
    y
}

/// `∂L/∂x` given `grad = ∂L/∂y` (same length as `x`).
pub fn backward(kind: Activation, x: &[f32], grad: &[f32]) -> Vec<f32> {
    assert_eq!(x.len(), grad.len(), "activation backward: gradient length");
    let mut out = vec![0.0f32; x.len()];
    out.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK).zip(grad.par_chunks(CHUNK)))
        .for_each(|(os, (xs, gs))| {
            for ((o, &x), &g) in os.iter_mut().zip(xs).zip(gs) {
                *o = g * derivative(kind, x);
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const KINDS: [Activation; 2] = [
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
        match kind {
            Activation::Softplus => (x.max(0.0) + (-x.abs()).exp().ln_1p(), s),
            Activation::Sigmoid { lo, span } => {
                let (lo, span) = (f64::from(lo), f64::from(span));
                // σ(1 − σ) without f64's own cancellation in 1 − σ.
                let e = (-x.abs()).exp();
                (s * span + lo, span * e / ((1.0 + e) * (1.0 + e)))
            }
        }
    }

    /// Both activations and derivatives against f64 over [−100, 100] (dense near 0) across
    /// chunk boundaries: libm's exp and ln_1p are within 1 ulp, and the few roundings after
    /// them add ≲ 4 ulp, so 1e-6 relative (with a 1e-30 floor for underflowed tails).
    #[test]
    fn values_and_derivatives_match_f64() {
        let n = 2 * CHUNK + 33;
        let x: Vec<f32> = (0..n)
            .map(|i| {
                let t = i as f64 / (n - 1) as f64 * 2.0 - 1.0;
                (100.0 * t * t * t) as f32
            })
            .collect();
        let ones = vec![1.0f32; n];
        for kind in KINDS {
            let y = forward(kind, &x);
            let d = backward(kind, &x, &ones);
            for i in 0..n {
                let (ey, ed) = exact(kind, x[i]);
                let (ty, td) = (1e-6 * ey.abs() + 1e-30, 1e-6 * ed.abs() + 1e-30);
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

    /// The upstream gradient scales the derivative; infinities give finite values and
    /// derivatives (softplus(+∞) = +∞ aside).
    #[test]
    fn the_upstream_gradient_scales_and_the_tails_are_finite() {
        let x = [f32::NEG_INFINITY, -1e4, -3.0, 0.0, 3.0, 1e4];
        let g = [2.0f32, -3.0, 0.5, 4.0, -1.0, 2.0];
        for kind in KINDS {
            let d1 = backward(kind, &x, &[1.0; 6]);
            let dg = backward(kind, &x, &g);
            for i in 0..x.len() {
                assert_eq!(dg[i], g[i] * d1[i], "{kind:?} x = {}", x[i]);
            }
            assert!(d1.iter().all(|v| v.is_finite()));
            assert!(forward(kind, &x[..5]).iter().all(|v| v.is_finite()));
        }
        assert_eq!(
            forward(Activation::Softplus, &[f32::INFINITY])[0],
            f32::INFINITY
        );
    }
}
