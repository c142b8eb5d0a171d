//! CPU kernels shared by the NdArray and Flex backends: `&[f32]` slices in, `Vec<f32>` out,
//! rayon over blocks of Gaussians.
//!
//! The per-Gaussian math is in plain functions (one Gaussian's `[M, E]` tile at a time), so a
//! GPU port can mirror it one thread per (Gaussian, feature channel). Reductions over K (the
//! gradients of shared parameters) use a fixed block size and an ordered sum, so results do not
//! depend on the thread count or on scheduling.

pub mod conv;
pub mod scan;

/// Gaussians per rayon task: large enough to amortise scheduling, small enough to balance.
pub(crate) const BLOCK: usize = 256;

/// Element-wise sum of per-block partial gradients, in block order (deterministic).
pub(crate) fn sum_partials(partials: Vec<Vec<f32>>, len: usize) -> Vec<f32> {
    let mut total = vec![0.0f32; len];
    for p in partials {
        for (t, v) in total.iter_mut().zip(p) {
            *t += v;
        }
    }
    total
}

/// e^x for the scan's decays (x = Δ·A ≤ 0), inlined so the hot loops carry no libm call and
/// its register spills: Cody–Waite reduction x = r ln2 + f with |f| ≤ ln2/2, e^f by its
/// degree-7 Taylor polynomial (truncation (ln2/2)^8/8! < 1e-8 relative), 2^r from the exponent
/// bits. Relative error ≲ 2 ulp on [−87, 88]; below −87 (e^x < 2e-38, subnormal) it returns 0,
/// above 88 +∞; NaN propagates.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    // ln 2 split so that r·LN2_HI is exact for |r| < 2^9.
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5·2^23: adding and subtracting it rounds |t| < 2^22 to the nearest integer.
    const ROUND: f32 = 12_582_912.0;
    if x.is_nan() {
        return x;
    }
    if x < -87.0 {
        return 0.0;
    }
    if x > 88.0 {
        return f32::INFINITY;
    }
    let r = (x * LOG2_E + ROUND) - ROUND;
    let f = (x - r * LN2_HI) - r * LN2_LO;
    let p = 1.0
        + f * (1.0
            + f * (0.5
                + f * (1.0 / 6.0
                    + f * (1.0 / 24.0
                        + f * (1.0 / 120.0 + f * (1.0 / 720.0 + f * (1.0 / 5040.0)))))));
    p * f32::from_bits(((r as i32 + 127) as u32) << 23)
}

/// Logistic sigmoid σ(v) = 1 / (1 + e^{−v}), finite for every finite or infinite `v`.
#[inline]
pub(crate) fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + (-v).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against f64 `exp` on a dense grid of [−87, 88]: ≤ 3 ulp (3.6e-7 relative); the tails are
    /// 0, +∞ and NaN.
    #[test]
    fn inline_exp_is_accurate() {
        let mut worst = 0.0f64;
        for i in 0..=1_750_000 {
            let x = -87.0 + i as f32 * 1e-4;
            let exact = f64::from(x).exp();
            worst = worst.max((f64::from(exp(x)) - exact).abs() / exact);
        }
        println!("exp: max relative error {worst:.2e}");
        assert!(worst <= 3.6e-7, "{worst}");
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(-0.0), 1.0);
        assert_eq!((exp(-1e30), exp(f32::NEG_INFINITY)), (0.0, 0.0));
        assert_eq!(exp(100.0), f32::INFINITY);
        assert!(exp(f32::NAN).is_nan());
    }
}
