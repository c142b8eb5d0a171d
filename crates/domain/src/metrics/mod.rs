//! Image-quality metrics: PSNR and SSIM for volumes (`[z][y][x]`) and projections
//! (`[view][row][col]`), following R²-Gaussian's evaluation (see [`ssim`] for the two SSIM border
//! conventions and the scikit-image cross-check).

pub mod psnr;
pub mod roi;
pub mod score_json;
pub mod ssim;

pub use psnr::psnr;
pub use roi::{Region, Roi, RoiSpec};
pub use ssim::{Border, Ssim3d, SsimParams, ssim_2d, ssim_3d, ssim_map, window_axes};

use crate::{Error, Result};
use ndarray::{ArrayView3, Axis};

/// The `q`-quantile of the finite values of `a` (the value at rank round((n − 1)·q)); 0 when
/// there is none. Display windows use it (white at the 99.9th percentile).
pub fn quantile(a: impl Iterator<Item = f32>, q: f64) -> f32 {
    let mut v: Vec<f32> = a.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    let k = ((v.len() - 1) as f64 * q).round() as usize;
    *v.select_nth_unstable_by(k, f32::total_cmp).1
}

/// Mean projection PSNR and SSIM, as R²-Gaussian's `metric_proj`: for every view whose reference
/// has a positive maximum, both images are divided by their own maximum (an image whose maximum is
/// ≤ 0 is left unscaled), then PSNR (peak 1) and 2-D SSIM (`params`) are averaged over views.
pub fn projection_metrics(
    pred: ArrayView3<f32>,
    truth: ArrayView3<f32>,
    params: &SsimParams,
) -> Result<(f64, f64)> {
    if pred.shape() != truth.shape() {
        return Err(Error::invalid(
            "projections",
            format!(
                "prediction shape {:?} differs from reference {:?}",
                pred.shape(),
                truth.shape()
            ),
        ));
    }
    let (mut p_sum, mut s_sum, mut n) = (0.0, 0.0, 0usize);
    for (p, t) in pred.axis_iter(Axis(0)).zip(truth.axis_iter(Axis(0))) {
        let tmax = t.fold(f32::NEG_INFINITY, |a, &b| a.max(b));
        if tmax <= 0.0 {
            continue;
        }
        let pmax = p.fold(f32::NEG_INFINITY, |a, &b| a.max(b));
        let p = if pmax > 0.0 {
            p.mapv(|x| x / pmax)
        } else {
            p.to_owned()
        };
        let t = t.mapv(|x| x / tmax);
        p_sum += psnr(p.view(), t.view(), 1.0)?;
        s_sum += ssim_2d(p.view(), t.view(), params)?;
        n += 1;
    }
    if n == 0 {
        return Err(Error::invalid(
            "projections",
            "every reference view is zero",
        ));
    }
    Ok((p_sum / n as f64, s_sum / n as f64))
}

#[cfg(test)]
mod tests;
