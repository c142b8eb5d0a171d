//! Run-time choice of the SIMD variants of the CPU kernels.
//!
//! The kernels are compiled twice: for the build's baseline target and with
//! `target_feature(enable = "avx2,fma")`. [`has_avx2_fma`] picks the second where the CPU has both
//! (checked once per process). The two variants differ only in rounding (fused multiply-adds),
//! and tests hold them to each other.

use std::sync::atomic::{AtomicBool, Ordering};

static FORCE_BASELINE: AtomicBool = AtomicBool::new(false);

/// Whether the AVX2+FMA kernel variants may run: the CPU has both and [`force_baseline`] is off.
pub fn has_avx2_fma() -> bool {
    !FORCE_BASELINE.load(Ordering::Relaxed) && detected()
}

/// Make [`has_avx2_fma`] answer false (`true`) or detect again (`false`), for tests and
/// benchmarks that compare the two variants. Process-wide: both variants compute the same
/// values up to rounding, so other work running meanwhile is unaffected.
pub fn force_baseline(on: bool) {
    FORCE_BASELINE.store(on, Ordering::Relaxed);
}

/// `a·b + c` with the rounding of a kernel variant: [`Separate`] rounds twice (plain `*`, `+`;
/// the baseline build), [`Fused`] once (`f32::mul_add`; only for code compiled with FMA, where it
/// is one instruction; elsewhere it is a slow libm call).
pub trait MulAdd: Copy {
    fn mul_add(a: f32, b: f32, c: f32) -> f32;
}

/// Unfused multiply-add (two roundings), for the baseline build.
#[derive(Clone, Copy, Debug)]
pub struct Separate;

/// Fused multiply-add (one rounding), for code compiled with `target_feature = "fma"`.
#[derive(Clone, Copy, Debug)]
pub struct Fused;

impl MulAdd for Separate {
    #[inline(always)]
    fn mul_add(a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
}

impl MulAdd for Fused {
    #[inline(always)]
    fn mul_add(a: f32, b: f32, c: f32) -> f32 {
        a.mul_add(b, c)
    }
}

fn detected() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *HAS.get_or_init(|| is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forcing_the_baseline_turns_the_simd_variants_off_and_back() {
        let cpu = detected();
        force_baseline(true);
        assert!(!has_avx2_fma());
        force_baseline(false);
        assert_eq!(has_avx2_fma(), cpu);
    }
}
