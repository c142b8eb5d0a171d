//! CPU kernels shared by the NdArray and Flex backends: `&[f32]` slices in, `Vec<f32>` out,
//! rayon over blocks of Gaussians.
//!
//! The per-Gaussian math is in plain functions (one Gaussian's `[M, E]` tile at a time), so a
//! GPU port can mirror it one thread per (Gaussian, feature channel). Reductions over K (the
//! gradients of shared parameters) use a fixed block size and an ordered sum, so results do not
//! depend on the thread count or on scheduling.

/// Defines `fn $name(wide: bool, args..)` that runs the generic kernel `$kernel::<Fused>` compiled
/// with AVX2 and FMA when `wide`, else `$kernel::<Separate>` for the build's baseline target. The
/// kernel is `#[inline(always)]`, so its whole body is compiled into both variants; they differ in
/// rounding only. Callers pass `wide = has_avx2()` (once per kernel call), or a test's choice.
macro_rules! dispatched {
    ($(#[$doc:meta])* fn $name:ident => $kernel:ident($($arg:ident: $ty:ty),* $(,)?)
        $(-> $ret:ty)?) => {
        $(#[$doc])*
        fn $name(wide: bool, $($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            fn avx2($($arg: $ty),*) $(-> $ret)? {
                $kernel::<$crate::cpu::math::Fused>($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            if wide {
                // SAFETY: `wide` is only set where `has_avx2` confirmed AVX2 and FMA.
                return unsafe { avx2($($arg),*) };
            }
            let _ = wide;
            $kernel::<$crate::cpu::math::Separate>($($arg),*)
        }
    };
}

pub mod activation;
pub mod conv;
mod math;
pub mod scan;
pub mod table;

/// Gaussians per rayon task: large enough to amortise scheduling, small enough to balance.
pub(crate) const BLOCK: usize = 256;

pub(crate) use prism_kernel::simd::has_avx2_fma as has_avx2;

pub(crate) use prism_kernel::cpu::sum_partials;
