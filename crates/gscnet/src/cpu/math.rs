//! Branch-free f32 `exp`, `ln`, softplus and sigmoid for the scan kernels.
//!
//! Every function is straight-line arithmetic, integer bit operations and value selects (no
//! early returns, no libm calls, no float→int conversions), so loops over them auto-vectorise.
//! Each is generic over [`MulAdd`]: [`Separate`] (two roundings) for the baseline build and
//! [`Fused`] (one rounding) inside `target_feature = "fma"` code, where `f32::mul_add` becomes a
//! single FMA instruction. The two variants differ in the last bits only.

pub(crate) use prism_kernel::simd::{Fused, MulAdd, Separate};

/// Below this argument [`exp`] returns 0 (e^−87 ≈ 1.6e-38, the edge of the normal range).
const EXP_LO: f32 = -87.0;
/// Above this argument [`exp`] returns +∞ (e^88 ≈ 1.7e38, so 2^r stays a normal float).
const EXP_HI: f32 = 88.0;
/// ln 2 split so that r·LN2_HI is exact for |r| < 2^9 (Cody–Waite).
const LN2_HI: f32 = 0.693_145_75;
const LN2_LO: f32 = 1.428_606_8e-6;
/// 1.5·2^23: `(t + ROUND) − ROUND` rounds |t| < 2^22 to the nearest integer r, and the bits of
/// `t + ROUND` end in r (two's complement), so 2^r is built without a float→int conversion.
const ROUND: f32 = 12_582_912.0;

/// e^x for any f32, branch-free: Cody–Waite reduction x = r ln2 + f (|f| ≤ ln2/2), e^f by its
/// degree-7 Taylor polynomial (truncation (ln2/2)^8/8! < 6e-9 relative), 2^r from exponent bits.
/// Accurate to a few ulp on [−87, 88] (tested against f64); x < −87 (and −∞) gives 0, x > 88
/// (and +∞) gives +∞, NaN gives NaN. The argument is clamped first and the tails are selected at
/// the end, so there is no branch for the decays e^{ΔA} (x ≤ 0) to vectorise around.
#[inline(always)]
pub(crate) fn exp<F: MulAdd>(x: f32) -> f32 {
    let xc = x.clamp(EXP_LO, EXP_HI);
    let t = F::mul_add(xc, std::f32::consts::LOG2_E, ROUND);
    let r = t - ROUND;
    let f = F::mul_add(r, -LN2_LO, F::mul_add(r, -LN2_HI, xc));
    let mut p = 1.0 / 5040.0;
    for c in [
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = F::mul_add(p, f, c);
    }
    // r + 127 ∈ [1, 254] after the clamp: a normal power of two. The shift drops ROUND's bits.
    let scale = f32::from_bits(t.to_bits().wrapping_add(127) << 23);
    let v = p * scale;
    let v = if x < EXP_LO { 0.0 } else { v };
    let v = if x > EXP_HI { f32::INFINITY } else { v };
    if x.is_nan() { x } else { v }
}

/// ln w for finite normal w > 0, branch-free: w = 2^e·s with s ∈ [√½, √2), then
/// ln s = 2 atanh(u) = 2(u + u³/3 + … + u⁹/9) with u = (s − 1)/(s + 1), |u| ≤ 0.172
/// (truncation u^10/11 < 2e-9 relative to u). Zero, subnormal, negative, infinite or NaN
/// arguments give unspecified finite or non-finite values (callers select around them).
#[inline(always)]
fn ln_normal<F: MulAdd>(w: f32) -> f32 {
    let bits = w.to_bits();
    // Mantissa in [1, 2); halve it (and bump the exponent) above √2.
    let s1 = f32::from_bits((bits & 0x007F_FFFF) | 0x3F80_0000);
    let big = s1 > std::f32::consts::SQRT_2;
    let s = if big { 0.5 * s1 } else { s1 };
    let e = ((bits >> 23) & 0xFF) as i32 - 127 + i32::from(big);
    let e = e as f32;
    let u = (s - 1.0) / (s + 1.0);
    let u2 = u * u;
    let mut q = 1.0 / 9.0;
    for c in [1.0 / 7.0, 1.0 / 5.0, 1.0 / 3.0] {
        q = F::mul_add(q, u2, c);
    }
    // 2u(1 + u²q) = 2u + 2u³q
    let ln_s = F::mul_add(2.0 * u * u2, q, 2.0 * u);
    F::mul_add(e, LN2_HI, F::mul_add(e, LN2_LO, ln_s))
}

/// softplus(z) = ln(1 + e^z), branch-free. z > 20 returns z (as Burn's `softplus`: the
/// correction e^{−z} < 2.1e-9 is below f32 resolution there). ln(1 + u) uses Goldberg's
/// correction (w = fl(1 + u), ln(w)·u/(w − 1) cancels the rounding of w), with ln(1 + u) = u
/// selected where w rounds to 1. z < −87 gives 0 (the true value is below 1.6e-38).
#[inline(always)]
pub(crate) fn softplus<F: MulAdd>(z: f32) -> f32 {
    // Clamp so the unselected lanes stay finite (ln of w ≤ 1 + e^20 is in range).
    let u = exp::<F>(z.min(20.0));
    let w = 1.0 + u;
    let den = if w == 1.0 { 1.0 } else { w - 1.0 };
    let l = ln_normal::<F>(w) * (u / den);
    let l = if w == 1.0 { u } else { l };
    // z itself above 20, and for NaN (which the clamp above turned into 20).
    if z <= 20.0 { l } else { z }
}

/// Logistic sigmoid σ(v) = 1 / (1 + e^{−v}), branch-free, finite for every finite or infinite
/// `v` (e^{−v} overflows to +∞ for v < −88, giving 0).
#[inline(always)]
pub(crate) fn sigmoid<F: MulAdd>(v: f32) -> f32 {
    1.0 / (1.0 + exp::<F>(-v))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `check` for both multiply-add variants (the fused one only where the CPU has FMA:
    /// elsewhere `f32::mul_add` is a correct but slow software fma, still fine for a test).
    fn both(mut check: impl FnMut(&str, fn(f32) -> f32, fn(f32) -> f32, fn(f32) -> f32)) {
        check(
            "separate",
            exp::<Separate>,
            softplus::<Separate>,
            ln_normal::<Separate>,
        );
        check("fused", exp::<Fused>, softplus::<Fused>, ln_normal::<Fused>);
    }

    /// Against f64 `exp` on a dense grid of [−87, 88] (step 1e-4, 1.75 M points): ≤ 1.5e-7
    /// relative (the reduction is exact to 2^-24 of f, the truncation < 6e-9, then the rounding
    /// of the Horner steps and of the final product, ½ ulp each; measured 9.9e-8).
    /// Tails: 0, +∞, NaN; e^0 = 1 exactly.
    #[test]
    fn exp_is_accurate_on_its_whole_range() {
        both(|name, exp, _, _| {
            let mut worst = 0.0f64;
            for i in 0..=1_750_000 {
                let x = -87.0 + i as f32 * 1e-4;
                let exact = f64::from(x).exp();
                worst = worst.max((f64::from(exp(x)) - exact).abs() / exact);
            }
            println!("exp ({name}): max relative error {worst:.2e}");
            assert!(worst <= 1.5e-7, "{name}: {worst}");
            assert_eq!((exp(0.0), exp(-0.0)), (1.0, 1.0), "{name}");
            assert_eq!((exp(-87.5), exp(-1e30)), (0.0, 0.0), "{name}");
            assert_eq!(exp(f32::NEG_INFINITY), 0.0, "{name}");
            assert_eq!(
                (exp(88.5), exp(f32::INFINITY)),
                (f32::INFINITY, f32::INFINITY)
            );
            assert!(exp(f32::NAN).is_nan(), "{name}");
        });
    }

    /// ln against f64 on [1, 2^30] (log-spaced, 400 k points, the softplus range and beyond):
    /// ≤ 2.4e-7 relative (2 ulp: the atanh series' ~1 ulp and the rounding of e·ln2 + ln s).
    /// ln 1 = 0 exactly.
    #[test]
    fn ln_is_accurate() {
        both(|name, _, _, ln| {
            let mut worst = 0.0f64;
            for i in 1..=400_000 {
                let w = (f64::from(i) * 30.0 / 400_000.0).exp2() as f32;
                let exact = f64::from(w).ln();
                worst = worst.max((f64::from(ln(w)) - exact).abs() / exact);
            }
            // Below 1 as well (not used by softplus, the same formula).
            for i in 1..=100_000 {
                let w = i as f32 * 1e-5;
                let exact = f64::from(w).ln();
                if exact != 0.0 {
                    worst = worst.max((f64::from(ln(w)) - exact).abs() / exact.abs());
                }
            }
            println!("ln ({name}): max relative error {worst:.2e}");
            assert!(worst <= 2.4e-7, "{name}: {worst}");
            assert_eq!(ln(1.0), 0.0, "{name}");
        });
    }

    /// softplus against f64 ln(1 + e^z) over [−80, 40] (step 1e-3): ≤ 4e-7 relative (the exp's
    /// 1.5e-7 carries over where ln(1 + u) ≈ u, plus the ln's 2.4e-7 and Goldberg's rounding;
    /// measured 2.7e-7). Above 20 it is z,
    /// below −87 it is 0, NaN stays NaN.
    #[test]
    fn softplus_is_accurate_in_both_tails() {
        both(|name, _, softplus, _| {
            let mut worst = 0.0f64;
            for i in 0..=120_000 {
                let z = -80.0 + i as f32 * 1e-3;
                let exact = f64::from(z).exp().ln_1p();
                let rel = (f64::from(softplus(z)) - exact).abs() / exact;
                worst = worst.max(rel);
            }
            println!("softplus ({name}): max relative error {worst:.2e}");
            assert!(worst <= 4e-7, "{name}: {worst}");
            assert_eq!(
                (softplus(25.0), softplus(f32::INFINITY)),
                (25.0, f32::INFINITY)
            );
            assert_eq!((softplus(-90.0), softplus(f32::NEG_INFINITY)), (0.0, 0.0));
            assert!(softplus(f32::NAN).is_nan(), "{name}");
        });
    }

    /// σ against f64 on [−87, 87]: ≤ 3e-7 relative (the exp's 1.5e-7, damped by e^{−v}/(1 + e^{−v}),
    /// plus the rounding of the sum and the division; measured 1.4e-7), exactly 0 and 1 in the
    /// far tails, σ(0) = ½.
    #[test]
    fn sigmoid_is_accurate_and_saturates() {
        for (name, sig) in [
            ("separate", sigmoid::<Separate> as fn(f32) -> f32),
            ("fused", sigmoid::<Fused>),
        ] {
            let mut worst = 0.0f64;
            for i in 0..=200_000 {
                let v = -87.0 + i as f32 * 8.7e-4;
                let exact = 1.0 / (1.0 + (-f64::from(v)).exp());
                worst = worst.max((f64::from(sig(v)) - exact).abs() / exact);
            }
            println!("sigmoid ({name}): max relative error {worst:.2e}");
            assert!(worst <= 3e-7, "{name}: {worst}");
            assert_eq!(sig(0.0), 0.5);
            assert_eq!((sig(-100.0), sig(f32::NEG_INFINITY)), (0.0, 0.0));
            assert_eq!((sig(100.0), sig(f32::INFINITY)), (1.0, 1.0));
        }
    }
}
