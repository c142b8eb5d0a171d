//! One Adam step as a single pass over a parameter tensor and its moments, multi-threaded.
//!
//! Every element goes through the same f32 operations, in the same order, as the composed form
//! ([`super::AdamParam::composed_step`]: Burn's scalar ops round their f64 scalars to f32 once),
//! so the two agree bit for bit; the fused form reads each tensor once and writes each result
//! once instead of a dozen element-wise passes on one thread.

use rayon::prelude::*;

/// Elements per task.
const CHUNK: usize = 4096;

/// The step's scalars as the composed form applies them (each rounded to f32 once; built by
/// [`super::AdamParam::step`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamScalars {
    pub beta1: f32,
    pub one_minus_beta1: f32,
    pub beta2: f32,
    pub one_minus_beta2: f32,
    /// Bias corrections `1 − β₁ᵗ`, `1 − β₂ᵗ`.
    pub correction1: f32,
    pub correction2: f32,
    pub eps: f32,
    pub lr: f32,
}

/// The new `(value, m1, m2)` after one step with gradient `grad` (all the same length).
pub fn adam_step(
    s: &AdamScalars,
    value: &[f32],
    m1: &[f32],
    m2: &[f32],
    grad: &[f32],
) -> [Vec<f32>; 3] {
    let n = value.len();
    assert!(
        m1.len() == n && m2.len() == n && grad.len() == n,
        "adam: the value, its moments and its gradient differ in length"
    );
    // Every slot is written below, so the outputs are not zeroed first (a step writes three
    // buffers of every parameter: zeroing them was a tenth of the step).
    let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| Vec::with_capacity(n));
    {
        let [ov, o1, o2] = out.each_mut().map(|v| &mut v.spare_capacity_mut()[..n]);
        ov.par_chunks_mut(CHUNK)
            .zip(o1.par_chunks_mut(CHUNK))
            .zip(o2.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(t, ((ov, o1), o2))| {
                let r = t * CHUNK..t * CHUNK + ov.len();
                let (v, a, b, g) = (&value[r.clone()], &m1[r.clone()], &m2[r.clone()], &grad[r]);
                for i in 0..ov.len() {
                    let m1n = a[i] * s.beta1 + g[i] * s.one_minus_beta1;
                    let m2n = b[i] * s.beta2 + g[i] * g[i] * s.one_minus_beta2;
                    let update = (m1n / s.correction1) / ((m2n / s.correction2).sqrt() + s.eps);
                    ov[i].write(v[i] - update * s.lr);
                    o1[i].write(m1n);
                    o2[i].write(m2n);
                }
            });
    }
    for v in &mut out {
        // SAFETY: the chunks above cover slots 0..n of each buffer (capacity ≥ n) and the loop
        // writes every slot of its chunk.
        unsafe { v.set_len(n) };
    }
    out
}
