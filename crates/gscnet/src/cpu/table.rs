//! Reading a curve table at every Gaussian's û by cubic convolution (Catmull–Rom, Keys'
//! a = −½), and its adjoint: the table lookup of [`crate::model::CurveModel`].
//!
//! The table holds `rows` nodes `û_j = −1 + (j − 1)·h` (one beyond each end of [−1, 1]) of `M`
//! channels. A û in node interval `n` (its position `p = (û + 1)/h`, `n = ⌊p⌋` clamped to
//! `[0, rows − 4]`, offset `s = p − n`) reads rows `n .. n + 4`:
//!
//! ```text
//! F(û) = ½ Σ_j w_j(s) T[n + j]          w = (−s³ + 2s² − s, 3s³ − 5s² + 2, −3s³ + 4s² + s, s³ − s²)
//! ∂T[n + j] += ½ w_j(s) ḡ               ∂û = ½ Σ_j w_j'(s) ⟨T[n + j], ḡ⟩ / h
//! ```
//!
//! (n is piecewise constant: no gradient through it.) The same arithmetic as the composed form
//! in [`crate::composed::table_lookup`]; one pass each way, rayon over blocks of Gaussians, the
//! table's gradient summed per block and the blocks in order.

use rayon::prelude::*;

use super::{BLOCK, sum_partials};

/// Where û reads a table of `rows` nodes spaced `h`: its first row and offset `s`.
#[inline(always)]
fn stencil(u: f32, h: f32, rows: usize) -> (usize, f32) {
    let p = (u + 1.0) / h;
    // `as` saturates (NaN → 0), and the clamp keeps the four rows inside the table.
    let n = p.floor().clamp(0.0, (rows - 4) as f32);
    (n as usize, p - n)
}

/// The four weights (halved form: the result is ½ Σ w_j T_j) at offset `s`.
#[inline(always)]
fn weights(s: f32) -> [f32; 4] {
    let (s2, s3) = (s * s, s * s * s);
    [
        -s3 + 2.0 * s2 - s,
        3.0 * s3 - 5.0 * s2 + 2.0,
        -3.0 * s3 + 4.0 * s2 + s,
        s3 - s2,
    ]
}

/// Their derivatives in `s`.
#[inline(always)]
fn slopes(s: f32) -> [f32; 4] {
    let s2 = s * s;
    [
        -3.0 * s2 + 4.0 * s - 1.0,
        9.0 * s2 - 10.0 * s,
        -9.0 * s2 + 8.0 * s + 1.0,
        3.0 * s2 - 2.0 * s,
    ]
}

/// The table's sizes: `rows` nodes (≥ 4) of `m` channels, spaced `h`.
#[derive(Clone, Copy, Debug)]
pub struct TableDims {
    pub rows: usize,
    pub m: usize,
    pub h: f32,
}

/// `F(û)` for every û, `[K, M]` row-major.
pub fn lookup_forward(dims: TableDims, table: &[f32], u: &[f32]) -> Vec<f32> {
    let TableDims { rows, m, h } = dims;
    assert!(
        rows >= 4 && table.len() == rows * m,
        "a [rows ≥ 4, M] table"
    );
    let mut out = vec![0.0f32; u.len() * m];
    out.par_chunks_mut(BLOCK * m)
        .zip(u.par_chunks(BLOCK))
        .for_each(|(out, u)| {
            for (o, &u) in out.chunks_exact_mut(m).zip(u) {
                let (n, s) = stencil(u, h, rows);
                let w = weights(s);
                for (c, o) in o.iter_mut().enumerate() {
                    let t = |j: usize| table[(n + j) * m + c];
                    *o = 0.5 * (w[0] * t(0) + w[1] * t(1) + w[2] * t(2) + w[3] * t(3));
                }
            }
        });
    out
}

/// Gradients of `⟨grad, F⟩`: the table's `[rows, M]` and û's `[K]`.
pub fn lookup_backward(
    dims: TableDims,
    table: &[f32],
    u: &[f32],
    grad: &[f32],
) -> (Vec<f32>, Vec<f32>) {
    let TableDims { rows, m, h } = dims;
    assert!(
        rows >= 4 && table.len() == rows * m,
        "a [rows ≥ 4, M] table"
    );
    assert_eq!(grad.len(), u.len() * m, "the upstream gradient is [K, M]");
    let mut gu = vec![0.0f32; u.len()];
    let partials: Vec<Vec<f32>> = gu
        .par_chunks_mut(BLOCK)
        .zip(u.par_chunks(BLOCK))
        .zip(grad.par_chunks(BLOCK * m))
        .map(|((gu, u), grad)| {
            let mut gt = vec![0.0f32; rows * m];
            for ((gu, &u), g) in gu.iter_mut().zip(u).zip(grad.chunks_exact(m)) {
                let (n, s) = stencil(u, h, rows);
                let (w, dw) = (weights(s), slopes(s));
                let mut ds = 0.0f32;
                for (j, (w, dw)) in w.iter().zip(dw).enumerate() {
                    let row = (n + j) * m;
                    for (c, &g) in g.iter().enumerate() {
                        gt[row + c] += 0.5 * w * g;
                        ds += dw * table[row + c] * g;
                    }
                }
                *gu = 0.5 * ds / h;
            }
            gt
        })
        .collect();
    (sum_partials(partials, rows * m), gu)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Keys' cubic convolution reproduces quadratics exactly: a table sampled from
    /// q(û) = 0.3 − 1.2û + 2.5û² (three channels: q, −q, 2q) reads q(û) at every û of [−1, 1]
    /// and its adjoint gives q'(û), to f32 rounding (values ≲ 4, so 1e-5 absolute).
    #[test]
    fn a_quadratic_table_is_read_exactly_with_its_slope() {
        let q = |x: f32| 0.3 - 1.2 * x + 2.5 * x * x;
        let dq = |x: f32| -1.2 + 5.0 * x;
        let (t, m) = (17usize, 3usize);
        let h = 2.0 / (t - 1) as f32;
        let scale = [1.0f32, -1.0, 2.0];
        let table: Vec<f32> = (0..t + 2)
            .flat_map(|j| {
                let x = -1.0 + (j as f32 - 1.0) * h;
                scale.map(|c| c * q(x))
            })
            .collect();
        let dims = TableDims { rows: t + 2, m, h };
        let u: Vec<f32> = (0..=200).map(|i| -1.0 + i as f32 / 100.0).collect();
        let f = lookup_forward(dims, &table, &u);
        for (i, &x) in u.iter().enumerate() {
            for (c, s) in scale.iter().enumerate() {
                let (got, want) = (f[i * m + c], s * q(x));
                assert!(
                    (got - want).abs() <= 1e-5,
                    "û = {x}, channel {c}: {got} vs {want}"
                );
            }
        }
        // ⟨ḡ, F⟩ with ḡ = (1, 0, 0) per Gaussian: ∂/∂û = q'(û); the table's gradient sums the
        // weights (½ Σ_j w_j = 1 per Gaussian).
        let grad: Vec<f32> = u.iter().flat_map(|_| [1.0, 0.0, 0.0]).collect();
        let (gt, gu) = lookup_backward(dims, &table, &u, &grad);
        for (&x, &g) in u.iter().zip(&gu) {
            assert!((g - dq(x)).abs() <= 1e-4, "û = {x}: {g} vs {}", dq(x));
        }
        let total: f32 = gt.iter().step_by(m).sum();
        assert!((total - u.len() as f32).abs() <= 1e-3, "{total}");
        assert!(gt.iter().skip(1).step_by(m).all(|&v| v == 0.0));
    }
}
