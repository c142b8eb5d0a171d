//! Structural similarity (Wang et al. 2004) with an 11×11 Gaussian window (σ = 1.5).
//!
//! Local statistics are Gaussian-weighted means (separable, f64) with population covariances;
//! `C1 = (0.01·L)²`, `C2 = (0.03·L)²` for data range `L`. Two border conventions:
//!
//! * [`Border::ZeroPad`] — R²-Gaussian / 3DGS (`loss_utils.ssim`): the image is zero-padded and the
//!   SSIM map is averaged over every pixel. This is the convention of the paper's tables and the
//!   default of [`ssim_3d`].
//! * [`Border::Crop`] — scikit-image `structural_similarity(gaussian_weights=True, sigma=1.5,
//!   use_sample_covariance=False, data_range=L)`: the map is averaged over pixels at least 5 from
//!   every edge, where the window never leaves the image.
//!
//! Both are verified against scikit-image / SciPy numbers stored in
//! `crates/domain/tests/fixtures/ssim/` with the script that produced them.
//!
//! 3-D SSIM ([`ssim_3d`]) follows R²-Gaussian: 2-D SSIM on every slice along each of the three
//! axes, skipping slices where the reference is all zero, mean per axis, then the mean of the axes
//! (of the axes whose slices hold the window: one slice of a 2-D scene scores as its 2-D SSIM).

use crate::{Error, Result};
use ndarray::{Array2, ArrayView2, ArrayView3, Axis};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Window half-width (11×11 window).
pub const RADIUS: usize = 5;

/// The axes of a `[z, y, x]` volume whose slices hold the 11×11 window (none for a volume too
/// small on every axis).
pub fn window_axes(shape: &[usize]) -> Vec<usize> {
    let window = 2 * RADIUS + 1;
    (0..3)
        .filter(|&k| (0..3).filter(|&j| j != k).all(|j| shape[j] >= window))
        .collect()
}

/// How the SSIM map treats the image border.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Border {
    /// Zero padding, mean over the whole map (R²-Gaussian).
    #[default]
    ZeroPad,
    /// Mean over the interior where the window fits (scikit-image).
    Crop,
}

/// SSIM parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimParams {
    /// Data range L (1 for images normalised to [0, 1]).
    pub data_range: f64,
    /// Gaussian σ in pixels; the window is 11×11.
    pub sigma: f64,
    pub border: Border,
}

impl Default for SsimParams {
    fn default() -> Self {
        SsimParams {
            data_range: 1.0,
            sigma: 1.5,
            border: Border::ZeroPad,
        }
    }
}

/// Per-axis and mean 3-D SSIM. `axes` are in array order: slices normal to z, y, x.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ssim3d {
    /// `None` for an axis whose slices are smaller than the window.
    pub axes: [Option<f64>; 3],
    pub mean: f64,
}

fn window(sigma: f64) -> [f64; 2 * RADIUS + 1] {
    let mut w = [0.0; 2 * RADIUS + 1];
    for (i, x) in w.iter_mut().enumerate() {
        let d = i as f64 - RADIUS as f64;
        *x = (-0.5 * d * d / (sigma * sigma)).exp();
    }
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|x| *x /= s);
    w
}

/// Separable Gaussian filter with zero padding (same size as the input).
fn blur(img: &Array2<f64>, w: &[f64]) -> Array2<f64> {
    let (h, wd) = img.dim();
    let r = RADIUS as isize;
    let mut tmp = Array2::<f64>::zeros((h, wd));
    for i in 0..h {
        for j in 0..wd {
            let mut s = 0.0;
            for (k, wk) in w.iter().enumerate() {
                let jj = j as isize + k as isize - r;
                if jj >= 0 && (jj as usize) < wd {
                    s += wk * img[[i, jj as usize]];
                }
            }
            tmp[[i, j]] = s;
        }
    }
    let mut out = Array2::<f64>::zeros((h, wd));
    for i in 0..h {
        for (k, wk) in w.iter().enumerate() {
            let ii = i as isize + k as isize - r;
            if ii >= 0 && (ii as usize) < h {
                let src = tmp.row(ii as usize);
                out.row_mut(i).zip_mut_with(&src, |o, s| *o += wk * s);
            }
        }
    }
    out
}

fn check_params(p: &SsimParams) -> Result<()> {
    if !(p.data_range.is_finite() && p.data_range > 0.0) {
        return Err(Error::invalid(
            "data_range",
            format!("must be positive (got {})", p.data_range),
        ));
    }
    if !(p.sigma.is_finite() && p.sigma > 0.0) {
        return Err(Error::invalid(
            "sigma",
            format!("must be positive (got {})", p.sigma),
        ));
    }
    Ok(())
}

/// Mean SSIM of two equally shaped 2-D images.
pub fn ssim_2d(a: ArrayView2<f32>, b: ArrayView2<f32>, p: &SsimParams) -> Result<f64> {
    let map = ssim_map(a, b, p)?;
    let (h, w) = map.dim();
    let (r0, r1, c0, c1) = match p.border {
        Border::ZeroPad => (0, h, 0, w),
        Border::Crop => (RADIUS, h - RADIUS, RADIUS, w - RADIUS),
    };
    let mut sum = 0.0;
    for i in r0..r1 {
        for j in c0..c1 {
            sum += map[[i, j]];
        }
    }
    Ok(sum / ((r1 - r0) * (c1 - c0)) as f64)
}

/// The SSIM map of two equally shaped 2-D images: the local SSIM at every pixel, the window
/// zero-padded at the border (the caller averages it over the pixels it scores; with
/// [`Border::Crop`] the image must hold the window).
pub fn ssim_map(a: ArrayView2<f32>, b: ArrayView2<f32>, p: &SsimParams) -> Result<Array2<f64>> {
    check_params(p)?;
    if a.shape() != b.shape() {
        return Err(Error::invalid(
            "prediction",
            format!(
                "shape {:?} differs from the reference {:?}",
                a.shape(),
                b.shape()
            ),
        ));
    }
    let (h, w) = a.dim();
    if h == 0 || w == 0 {
        return Err(Error::invalid("reference", "is empty"));
    }
    if p.border == Border::Crop && (h < 2 * RADIUS + 1 || w < 2 * RADIUS + 1) {
        return Err(Error::invalid(
            "reference",
            format!("a {h}×{w} image is smaller than the 11×11 window"),
        ));
    }
    let win = window(p.sigma);
    let x = a.mapv(|v| v as f64);
    let y = b.mapv(|v| v as f64);
    let mx = blur(&x, &win);
    let my = blur(&y, &win);
    let mxx = blur(&(&x * &x), &win);
    let myy = blur(&(&y * &y), &win);
    let mxy = blur(&(&x * &y), &win);
    let c1 = (0.01 * p.data_range).powi(2);
    let c2 = (0.03 * p.data_range).powi(2);
    Ok(Array2::from_shape_fn((h, w), |(i, j)| {
        let (ux, uy) = (mx[[i, j]], my[[i, j]]);
        let vx = mxx[[i, j]] - ux * ux;
        let vy = myy[[i, j]] - uy * uy;
        let vxy = mxy[[i, j]] - ux * uy;
        ((2.0 * ux * uy + c1) * (2.0 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
    }))
}

/// 3-D SSIM of `pred` against `truth` (both `[z][y][x]`), R²-Gaussian style (module docs).
/// An axis whose slices are smaller than the window (a thin slab, a 2-D scene's one slice) is
/// left out of the mean, so one slice scores as its 2-D SSIM; with zero padding, a volume too
/// small on every axis keeps all three.
pub fn ssim_3d(pred: ArrayView3<f32>, truth: ArrayView3<f32>, p: &SsimParams) -> Result<Ssim3d> {
    check_params(p)?;
    crate::error::ensure_shape("prediction", pred.shape(), truth.shape(), "the reference")?;
    let n = truth.shape();
    let mut scored = window_axes(n);
    if scored.is_empty() && p.border == Border::ZeroPad {
        scored = vec![0, 1, 2];
    }
    if scored.is_empty() {
        return Err(Error::invalid(
            "reference",
            format!(
                "a {}×{}×{} volume has no slice as large as the 11×11 window",
                n[0], n[1], n[2]
            ),
        ));
    }
    let mut axes = [None; 3];
    for &k in &scored {
        let vals: Vec<f64> = (0..n[k])
            .into_par_iter()
            .map(|i| {
                let t = truth.index_axis(Axis(k), i);
                if t.iter().all(|&v| v == 0.0) {
                    return Ok(None);
                }
                ssim_2d(pred.index_axis(Axis(k), i), t, p).map(Some)
            })
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .flatten()
            .collect();
        if vals.is_empty() {
            return Err(Error::invalid(
                "reference",
                "the reference volume is all zero",
            ));
        }
        axes[k] = Some(vals.iter().sum::<f64>() / vals.len() as f64);
    }
    let used: Vec<f64> = axes.iter().flatten().copied().collect();
    Ok(Ssim3d {
        axes,
        mean: used.iter().sum::<f64>() / used.len() as f64,
    })
}
