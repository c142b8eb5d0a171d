//! CPU kernels shared by the NdArray and Flex backends: `&[f32]` slices in, `Vec<f32>` out,
//! rayon over blocks of Gaussians.
//!
//! The per-Gaussian math is in plain functions (one Gaussian's `[M, E]` tile at a time), so a
//! GPU port can mirror it one thread per (Gaussian, feature channel). Reductions over K (the
//! gradients of shared parameters) use a fixed block size and an ordered sum, so results do not
//! depend on the thread count or on scheduling.

pub mod conv;
mod math;
pub mod scan;

/// Gaussians per rayon task: large enough to amortise scheduling, small enough to balance.
pub(crate) const BLOCK: usize = 256;

/// Whether the running CPU has AVX2 and FMA (checked once per process), so the kernels may take
/// their `target_feature(enable = "avx2,fma")` variants.
pub(crate) fn has_avx2() -> bool {
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

/// Logistic sigmoid σ(v) = 1 / (1 + e^{−v}), finite for every finite or infinite `v`.
#[inline]
pub(crate) fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + (-v).exp())
}
