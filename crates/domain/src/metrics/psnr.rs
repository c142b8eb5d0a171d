//! Peak signal-to-noise ratio.

use crate::{Error, Result};
use ndarray::{ArrayView, Dimension};

/// `10·log10(peak² / MSE)` in dB over all elements (R²-Gaussian uses peak 1 on volumes normalised to
/// [0, 1]). The mean is accumulated in f64. Identical inputs give `+∞`.
pub fn psnr<D: Dimension>(
    pred: ArrayView<f32, D>,
    truth: ArrayView<f32, D>,
    peak: f64,
) -> Result<f64> {
    crate::error::ensure_shape("prediction", pred.shape(), truth.shape(), "the reference")?;
    if truth.is_empty() {
        return Err(Error::invalid("reference", "is empty"));
    }
    if !(peak.is_finite() && peak > 0.0) {
        return Err(Error::invalid(
            "peak",
            format!("must be positive and finite (got {peak})"),
        ));
    }
    let se: f64 = pred
        .iter()
        .zip(truth.iter())
        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
        .sum();
    let mse = se / truth.len() as f64;
    Ok(10.0 * (peak * peak / mse).log10())
}
