//! The SSIM window and constants (R²-Gaussian's: an 11×11 Gaussian window, σ = 1.5, separable;
//! C₁ = 0.01², C₂ = 0.03² on raw projection values), shared by the fused op and the composed form.

/// Side of the SSIM window (pixels).
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of the SSIM window (pixels).
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM's stabilising constants for a data range of 1: (0.01)² and (0.03)².
pub const C1: f64 = 0.01 * 0.01;
/// See [`C1`].
pub const C2: f64 = 0.03 * 0.03;

/// The normalised 1-D SSIM window (f32 weights of an f64 Gaussian, summing to 1 in f64).
pub fn ssim_window() -> [f32; SSIM_WINDOW] {
    let c = (SSIM_WINDOW / 2) as f64;
    let w: [f64; SSIM_WINDOW] = std::array::from_fn(|i| {
        (-((i as f64 - c).powi(2)) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp()
    });
    let total: f64 = w.iter().sum();
    w.map(|v| (v / total) as f32)
}
