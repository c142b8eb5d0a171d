//! The evaluation protocol: how a reconstructed volume is scored against its reference.
//!
//! 1. **Normalisation**: prediction and reference are divided by the reference's maximum (peak 1;
//!    R²-Gaussian's convention and the paper's "intensity normalization").
//! 2. **Grid**: the reconstruction's own (`native`), or both volumes resampled to `n³`
//!    (trilinear, voxel centres mapped box to box; the paper evaluates on 256³).
//! 3. **Volume metrics**: PSNR over the whole 3-D volume (peak 1); SSIM as R²-Gaussian computes it
//!    (2-D SSIM, 11×11 Gaussian window σ = 1.5, zero-padded, averaged over the non-empty slices of
//!    all three axes), and with scikit-image's border convention for reference.
//! 4. **Slice metrics** (the paper's "averaged over all reconstructed slices"): PSNR, 2-D SSIM and
//!    LPIPS of every slice along the chosen axes (`axial`: z, the default; `all`: z, y and x)
//!    whose reference slice is not all zero, averaged. A slice identical to its reference counts
//!    as [`PSNR_CAP`] dB. LPIPS sees each slice clipped to [0, 1].
//!
//! The paper names neither the slice axes nor the resampling; both are recorded in
//! `metrics.json` (`protocol`), so a table states what it measured.

use super::lpips::Lpips;
use crate::{Error, Result};
use ndarray::{Array3, ArrayView2, ArrayView3, Axis};
use prism_domain::metrics::{Border, SsimParams, psnr, ssim_2d, ssim_3d};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The PSNR (dB) a slice identical to its reference counts as (its MSE is 0).
pub const PSNR_CAP: f64 = 100.0;
/// Slices per LPIPS batch (bounds the trunk's activations in memory).
const LPIPS_BATCH: usize = 16;

/// The slices of the slice metrics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SliceAxes {
    /// Axial slices (constant z).
    #[default]
    Axial,
    /// Slices along z, y and x.
    All,
}

/// How volumes are scored (recorded in `metrics.json`).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Protocol {
    /// Resample both volumes to `grid³` before scoring; `None` (the default): the native grid.
    pub grid: Option<usize>,
    pub slices: SliceAxes,
}

/// The protocol and, when weights were given, the LPIPS network.
#[derive(Default)]
pub struct Evaluation {
    pub protocol: Protocol,
    pub lpips: Option<(Lpips, PathBuf)>,
}

/// The protocol as `metrics.json` records it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProtocolRecord {
    pub normalisation: String,
    /// `native n_z×n_y×n_x` or `resized to n³ (trilinear)`.
    pub grid: String,
    pub slices: SliceAxes,
    /// `alex` / `vgg` and the weights file, or why LPIPS is absent.
    pub lpips: String,
    /// How the test-view projections were made (Joseph re-projection of the volume, or the
    /// Gaussian method's own renderer).
    pub projections: String,
}

impl Evaluation {
    /// The record of this evaluation for volumes of `shape` (`[z, y, x]`), with projection
    /// metrics made as `projections` says.
    pub fn record(&self, shape: &[usize], projections: &str) -> ProtocolRecord {
        ProtocolRecord {
            normalisation: "prediction and reference divided by the reference's maximum; PSNR \
                            peak 1, SSIM data range 1"
                .into(),
            grid: match self.protocol.grid {
                None => format!("native {}×{}×{}", shape[0], shape[1], shape[2]),
                Some(n) => format!("resized to {n}³ (trilinear)"),
            },
            slices: self.protocol.slices,
            lpips: match &self.lpips {
                Some((net, path)) => {
                    format!("{}, v0.1, weights {}", net.net().name(), path.display())
                }
                None => "not computed: no weights given (prism recon --lpips-weights FILE; \
                         scripts/lpips_weights.py makes the file)"
                    .into(),
            },
            projections: projections.into(),
        }
    }
}

/// The scores of one volume against its reference.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// 3-D PSNR (dB) and SSIM (R²-Gaussian's convention) of the normalised volume.
    pub psnr: f64,
    pub ssim: f64,
    /// 3-D SSIM with scikit-image's border convention (interior of each slice), for reference.
    pub ssim_skimage: f64,
    /// Means over the scored slices (see the module docs).
    pub psnr_slices: f64,
    pub ssim_slices: f64,
    /// Mean LPIPS over the scored slices; `None` without LPIPS weights.
    pub lpips: Option<f64>,
    /// Number of slices scored.
    pub slices: usize,
}

/// Score `pred` against `truth` (mm⁻¹, `[z][y][x]`) under `eval`.
pub fn score(pred: ArrayView3<f32>, truth: ArrayView3<f32>, eval: &Evaluation) -> Result<Scores> {
    let peak = truth.fold(0.0f32, |a, &b| a.max(b));
    if peak <= 0.0 {
        return Err(Error::invalid(
            "references",
            "the reference volume has no positive value",
        ));
    }
    let mut t = truth.mapv(|x| x / peak);
    let mut p = pred.mapv(|x| x / peak);
    if let Some(n) = eval.protocol.grid {
        t = resize(t.view(), [n, n, n])?;
        p = resize(p.view(), [n, n, n])?;
    }
    let zero_pad = SsimParams::default();
    let crop = SsimParams {
        border: Border::Crop,
        ..zero_pad
    };
    let axes: &[usize] = match eval.protocol.slices {
        SliceAxes::Axial => &[0],
        SliceAxes::All => &[0, 1, 2],
    };
    let (mut psnr_sum, mut ssim_sum, mut lpips_sum, mut n) = (0.0, 0.0, 0.0, 0usize);
    for &axis in axes {
        let used: Vec<usize> = (0..t.shape()[axis])
            .filter(|&i| t.index_axis(Axis(axis), i).iter().any(|&v| v != 0.0))
            .collect();
        for &i in &used {
            let (ps, ts) = (p.index_axis(Axis(axis), i), t.index_axis(Axis(axis), i));
            psnr_sum += psnr(ps, ts, 1.0)?.min(PSNR_CAP);
            ssim_sum += ssim_2d(ps, ts, &zero_pad)?;
        }
        if let Some((net, _)) = &eval.lpips {
            let clip = |v: ArrayView2<f32>| v.mapv(|x| x.clamp(0.0, 1.0));
            for chunk in used.chunks(LPIPS_BATCH) {
                let a: Vec<_> = chunk
                    .iter()
                    .map(|&i| clip(p.index_axis(Axis(axis), i)))
                    .collect();
                let b: Vec<_> = chunk
                    .iter()
                    .map(|&i| clip(t.index_axis(Axis(axis), i)))
                    .collect();
                let av: Vec<_> = a.iter().map(|x| x.view()).collect();
                let bv: Vec<_> = b.iter().map(|x| x.view()).collect();
                lpips_sum += net.distances(&av, &bv)?.iter().sum::<f64>();
            }
        }
        n += used.len();
    }
    if n == 0 {
        return Err(Error::invalid(
            "references",
            "every reference slice is zero",
        ));
    }
    let nf = n as f64;
    Ok(Scores {
        psnr: psnr(p.view(), t.view(), 1.0)?,
        ssim: ssim_3d(p.view(), t.view(), &zero_pad)?.mean,
        ssim_skimage: ssim_3d(p.view(), t.view(), &crop)?.mean,
        psnr_slices: psnr_sum / nf,
        ssim_slices: ssim_sum / nf,
        lpips: eval.lpips.as_ref().map(|_| lpips_sum / nf),
        slices: n,
    })
}

/// `vol` resampled trilinearly to `shape` (`[z, y, x]`) over the same box: output voxel centre
/// `i` sits at input index `(i + ½)·N/n − ½` (clamped to the grid) on each axis.
pub fn resize(vol: ArrayView3<f32>, shape: [usize; 3]) -> Result<Array3<f32>> {
    if vol.is_empty() || shape.contains(&0) {
        return Err(Error::invalid("grid", "cannot resize an empty volume"));
    }
    let src = vol.shape().to_vec();
    // Per axis and output index: the two input indices and the weight of the upper one.
    let taps = |a: usize| -> Vec<(usize, usize, f32)> {
        let (n_in, n_out) = (src[a], shape[a]);
        (0..n_out)
            .map(|i| {
                let x = ((i as f64 + 0.5) * n_in as f64 / n_out as f64 - 0.5)
                    .clamp(0.0, (n_in - 1) as f64);
                let lo = x.floor() as usize;
                let hi = (lo + 1).min(n_in - 1);
                (lo, hi, (x - lo as f64) as f32)
            })
            .collect()
    };
    let (tz, ty, tx) = (taps(0), taps(1), taps(2));
    let mut out = Array3::<f32>::zeros(shape);
    for (z, &(z0, z1, fz)) in tz.iter().enumerate() {
        for (y, &(y0, y1, fy)) in ty.iter().enumerate() {
            for (x, &(x0, x1, fx)) in tx.iter().enumerate() {
                let lerp = |a: f32, b: f32, f: f32| a + (b - a) * f;
                let plane = |zz: usize| {
                    lerp(
                        lerp(vol[[zz, y0, x0]], vol[[zz, y0, x1]], fx),
                        lerp(vol[[zz, y1, x0]], vol[[zz, y1, x1]], fx),
                        fy,
                    )
                };
                out[[z, y, x]] = lerp(plane(z0), plane(z1), fz);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resizing_keeps_linear_fields_and_the_native_grid() {
        // A field linear in the voxel centres' positions is reproduced exactly inside the box.
        let n = 8;
        let vol = Array3::from_shape_fn((n, n, n), |(z, y, x)| {
            (z as f32 + 0.5) * 1.0 + (y as f32 + 0.5) * 2.0 + (x as f32 + 0.5) * 3.0
        });
        let up = resize(vol.view(), [32, 32, 32]).unwrap();
        let s = n as f32 / 32.0;
        for (z, y, x) in [(8, 8, 8), (16, 4, 27), (23, 20, 12)] {
            let want =
                (z as f32 + 0.5) * s + 2.0 * (y as f32 + 0.5) * s + 3.0 * (x as f32 + 0.5) * s;
            assert!((up[[z, y, x]] - want).abs() < 1e-4, "{z} {y} {x}");
        }
        // The same shape is the identity.
        assert_eq!(resize(vol.view(), [n, n, n]).unwrap(), vol);
    }

    #[test]
    fn slice_scores_skip_empty_slices_and_cap_identical_ones() {
        let mut truth = Array3::<f32>::zeros((12, 12, 12));
        truth.slice_mut(ndarray::s![2..10, 2..10, 2..10]).fill(2.0);
        let eval = Evaluation::default();
        let same = score(truth.view(), truth.view(), &eval).unwrap();
        assert_eq!(same.slices, 8, "the four empty axial slices are left out");
        assert_eq!(same.psnr_slices, PSNR_CAP);
        assert!((same.ssim_slices - 1.0).abs() < 1e-12);
        assert!(same.lpips.is_none());
        // A uniform error of 0.1 (after normalisation by the peak 2) on the occupied slices:
        // each slice's PSNR is 20 dB; the volume's counts the error-free empty slices too.
        let pred = truth.mapv(|v| if v > 0.0 { v + 0.2 } else { 0.0 });
        let s = score(pred.view(), truth.view(), &eval).unwrap();
        let per_slice = 10.0 * (1.0f64 / (0.1 * 0.1 * 64.0 / 144.0)).log10();
        assert!(
            (s.psnr_slices - per_slice).abs() < 1e-4,
            "{}",
            s.psnr_slices
        );
        assert!(s.psnr > s.psnr_slices);
        let all = Evaluation {
            protocol: Protocol {
                grid: None,
                slices: SliceAxes::All,
            },
            lpips: None,
        };
        assert_eq!(
            score(pred.view(), truth.view(), &all).unwrap().slices,
            3 * 8
        );
        let e = score(pred.view(), Array3::zeros((2, 2, 2)).view(), &eval);
        assert!(e.is_err());
    }
}
