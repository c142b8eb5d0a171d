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
//! 5. **Region of interest** (optional, `roi`): every metric above restricted to the object mask
//!    or the complete-data region of [`prism_domain::metrics::roi`] (PSNR over the mask's voxels,
//!    SSIM maps averaged over its pixels); LPIPS still sees whole slices (those holding a mask
//!    pixel).
//!
//! The paper names neither the slice axes nor the resampling; both are recorded in
//! `metrics.json` (`protocol`), so a table states what it measured.

use super::lpips::Lpips;
use crate::{Error, Result};
use ndarray::{Array3, ArrayView2, ArrayView3, Axis};
use prism_domain::metrics::ssim::RADIUS as SSIM_RADIUS;
use prism_domain::metrics::{
    Border, Roi, RoiSpec, SsimParams, psnr, score_json, ssim_2d, ssim_3d, ssim_map, window_axes,
};
use prism_domain::scene::Scene;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;

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
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Protocol {
    /// Resample both volumes to `grid³` before scoring; `None` (the default): the native grid.
    pub grid: Option<usize>,
    pub slices: SliceAxes,
    /// Score inside the object only (`None`, the default: every voxel).
    pub roi: Option<RoiSpec>,
}

/// The evaluation grid's edge lengths accepted (the upper end: 4096³ voxels of two f32 volumes
/// are already 0.5 TB).
pub const GRID_RANGE: std::ops::RangeInclusive<usize> = 2..=4096;

/// Bytes per voxel of the evaluation (both volumes normalised by the reference's peak, f32; SSIM
/// works slice by slice) and of a classic method's working volumes. Measured as the slope of peak
/// resident size against the voxel count beyond the scene and the output volumes (64³ → 160³,
/// 3 channels): FDK 9.4, CGLS 13, SART 9 bytes (its cached column sums aside), NAF 5; an
/// R²-Gaussian run at 256³ scores at about 23. It was 64 (3-D SSIM's f64 moment maps, since
/// replaced by slice-wise SSIM), which put FDK's estimate 60 % high at 128³.
pub const VOXEL_BYTES: u64 = 16;

impl Protocol {
    /// Refuse an evaluation grid outside [`GRID_RANGE`] (`field` names where it was given).
    pub fn check_grid(grid: Option<usize>, field: &str) -> prism_domain::Result<()> {
        match grid {
            Some(n) if !GRID_RANGE.contains(&n) => Err(prism_domain::Error::invalid(
                field,
                format!(
                    "expected an edge length in {}..={}, got {n}",
                    GRID_RANGE.start(),
                    GRID_RANGE.end()
                ),
            )),
            _ => Ok(()),
        }
    }

    /// Add what scoring holds at its peak to `f`: one channel's prediction and reference
    /// resampled to the evaluation grid (or on the scene's own) normalised by its reference's peak.
    pub fn add_footprint(
        &self,
        f: &mut prism_domain::memory::Footprint,
        phase: &str,
        native_voxels: usize,
    ) {
        let voxels = self.grid.map_or(native_voxels, |n| n.saturating_pow(3));
        let on = self
            .grid
            .map_or("the native grid".to_string(), |n| format!("{n}³"));
        f.add_in(
            phase,
            format!("scoring one channel on {on} (both volumes, normalised)"),
            prism_domain::memory::bytes(voxels, VOXEL_BYTES as usize),
        );
    }
}

/// The protocol and, when weights were given, the LPIPS network (shared: a suite's cells
/// score with one network under their scenes' protocols).
#[derive(Clone, Default)]
pub struct Evaluation {
    pub protocol: Protocol,
    pub lpips: Option<Arc<(Lpips, PathBuf)>>,
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
    /// Where the volume metrics were taken: `the whole grid`, or the object mask and its size.
    #[serde(default = "whole_grid")]
    pub roi: String,
}

fn whole_grid() -> String {
    "the whole grid".into()
}

impl Evaluation {
    /// The region of interest of `scene` under this protocol (`None` without `roi` or without
    /// references); errors name `evaluation.roi.<field>`.
    pub fn roi(&self, scene: &Scene) -> Result<Option<Roi>> {
        let (Some(spec), Some(refs)) = (&self.protocol.roi, &scene.references) else {
            return Ok(None);
        };
        Roi::new(refs.view(), &scene.geometry, spec)
            .map(Some)
            .map_err(|e| Error::from(e).under("evaluation.roi"))
    }

    /// This evaluation without LPIPS (a trial, a training curve).
    pub fn without_lpips(&self) -> Evaluation {
        Evaluation {
            lpips: None,
            ..self.clone()
        }
    }

    /// Try this evaluation on `scene` before anything is reconstructed: its mask is made and
    /// every reference scored against itself, so an evaluation that cannot run (a grid smaller
    /// than the SSIM window, a reference with no positive value, a mask that cannot be made)
    /// fails at once instead of after the reconstruction, which it would lose. LPIPS is left
    /// out of the trial (its network runs on every slice and fails only on its weights, read
    /// when the evaluation was made).
    pub fn check(&self, scene: &Scene) -> Result<()> {
        let roi = self.roi(scene)?;
        let trial = self.without_lpips();
        if let Some(refs) = &scene.references {
            for (c, ch) in scene.channels.iter().enumerate() {
                let r = refs.index_axis(ndarray::Axis(0), c);
                score(r, r, &trial, roi.as_ref())
                    .map_err(|e| e.under(&format!("evaluation of channel `{}`", ch.label)))?;
            }
        }
        Ok(())
    }

    /// The record of this evaluation for volumes of `shape` (`[z, y, x]`), with projection
    /// metrics made as `projections` says, inside `roi` when there is one.
    pub fn record(&self, shape: &[usize], projections: &str, roi: Option<&Roi>) -> ProtocolRecord {
        ProtocolRecord {
            normalisation: "prediction and reference divided by the reference's maximum; PSNR \
                            peak 1, SSIM data range 1"
                .into(),
            grid: match self.protocol.grid {
                None => format!("native {}×{}×{}", shape[0], shape[1], shape[2]),
                Some(n) => format!("resized to {n}³ (trilinear)"),
            },
            slices: self.protocol.slices,
            lpips: match self.lpips.as_deref() {
                Some((net, path)) => {
                    format!("{}, v0.1, weights {}", net.net().name(), path.display())
                }
                None => "not computed: no weights given (prism recon --lpips-weights FILE; \
                         scripts/lpips_weights.py makes the file)"
                    .into(),
            },
            projections: projections.into(),
            roi: match roi {
                Some(r) => r.describe(),
                None => "the whole grid".into(),
            },
        }
    }
}

/// The scores of one volume against its reference.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// 3-D PSNR (dB; `"inf"` in JSON for a volume identical to its reference, see
    /// [`score_json`]) and SSIM (R²-Gaussian's convention) of the normalised volume.
    #[serde(with = "score_json")]
    pub psnr: f64,
    #[serde(with = "score_json")]
    pub ssim: f64,
    /// 3-D SSIM with scikit-image's border convention (interior of each slice), for reference
    /// (NaN when a region of interest has no pixel in any slice's interior).
    #[serde(with = "score_json")]
    pub ssim_skimage: f64,
    /// Means over the scored slices (see the module docs).
    #[serde(with = "score_json")]
    pub psnr_slices: f64,
    #[serde(with = "score_json")]
    pub ssim_slices: f64,
    /// Mean LPIPS over the scored slices; `None` without LPIPS weights.
    #[serde(with = "score_json::option", default)]
    pub lpips: Option<f64>,
    /// Number of slices scored.
    pub slices: usize,
}

/// Score `pred` against `truth` (mm⁻¹, `[z][y][x]`) under `eval`, inside `roi` when given
/// ([`Evaluation::roi`] of the scene; the native grid's mask).
pub fn score(
    pred: ArrayView3<f32>,
    truth: ArrayView3<f32>,
    eval: &Evaluation,
    roi: Option<&Roi>,
) -> Result<Scores> {
    let peak = truth.fold(0.0f32, |a, &b| a.max(b));
    if peak <= 0.0 {
        return Err(Error::invalid(
            "references",
            "the reference volume has no positive value",
        ));
    }
    let mut t = truth.mapv(|x| x / peak);
    let mut p = pred.mapv(|x| x / peak);
    let mut mask = roi.map(|r| r.mask.clone());
    if let Some(n) = eval.protocol.grid {
        t = resize(t.view(), [n, n, n])?;
        p = resize(p.view(), [n, n, n])?;
        mask = match mask {
            Some(m) => {
                Some(resize(m.mapv(|b| b as u8 as f32).view(), [n, n, n])?.mapv(|v| v >= 0.5))
            }
            None => None,
        };
    }
    if let Some(mask) = &mask {
        prism_domain::error::ensure_shape("roi", mask.shape(), t.shape(), "the reference")?;
        return score_in(p, t, mask, eval);
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
        // Slices scored in parallel, summed in order (the same sums as one loop).
        let scores: Vec<(f64, f64)> = used
            .par_iter()
            .map(|&i| {
                let (ps, ts) = (p.index_axis(Axis(axis), i), t.index_axis(Axis(axis), i));
                Ok((
                    psnr(ps, ts, 1.0)?.min(PSNR_CAP),
                    ssim_2d(ps, ts, &zero_pad)?,
                ))
            })
            .collect::<Result<_>>()?;
        for (a, b) in scores {
            psnr_sum += a;
            ssim_sum += b;
        }
        if let Some((net, _)) = eval.lpips.as_deref() {
            lpips_sum += lpips_of(net, &p, &t, axis, &used)?;
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

/// The sum of LPIPS over slices `used` along `axis`, each clipped to [0, 1].
fn lpips_of(
    net: &Lpips,
    p: &Array3<f32>,
    t: &Array3<f32>,
    axis: usize,
    used: &[usize],
) -> Result<f64> {
    let clip = |v: ArrayView2<f32>| v.mapv(|x| x.clamp(0.0, 1.0));
    let mut sum = 0.0;
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
        sum += net.distances(&av, &bv)?.iter().sum::<f64>();
    }
    Ok(sum)
}

/// Score normalised `p` against `t` inside `mask` (module docs, 5).
fn score_in(
    p: Array3<f32>,
    t: Array3<f32>,
    mask: &Array3<bool>,
    eval: &Evaluation,
) -> Result<Scores> {
    let params = SsimParams::default();
    let n = t.shape().to_vec();
    // Volume SSIM: the axes whose slices hold the window (all three when none does, as
    // `ssim_3d` with zero padding); slice metrics: the protocol's axes.
    let mut volume_axes = window_axes(&n);
    if volume_axes.is_empty() {
        volume_axes = vec![0, 1, 2];
    }
    let slice_axes: &[usize] = match eval.protocol.slices {
        SliceAxes::Axial => &[0],
        SliceAxes::All => &[0, 1, 2],
    };
    // Per slice of every axis either needs, made once: the squared-error sum, the SSIM map's sums
    // (zero padded; and over the interior, where the window fits: scikit-image's convention)
    // and their pixel counts, over the mask's pixels.
    let slice = |axis: usize, i: usize| -> Result<[f64; 5]> {
        let m = mask.index_axis(Axis(axis), i);
        if !m.iter().any(|&b| b) {
            return Ok([0.0; 5]);
        }
        let (ps, ts) = (p.index_axis(Axis(axis), i), t.index_axis(Axis(axis), i));
        let map = ssim_map(ps, ts, &params)?;
        let (h, w) = m.dim();
        let r = SSIM_RADIUS;
        let mut acc = [0.0; 5];
        for ((y, x), &inside) in m.indexed_iter() {
            if inside {
                acc[0] += (ps[[y, x]] as f64 - ts[[y, x]] as f64).powi(2);
                acc[1] += map[[y, x]];
                acc[2] += 1.0;
                if y >= r && x >= r && y + r < h && x + r < w {
                    acc[3] += map[[y, x]];
                    acc[4] += 1.0;
                }
            }
        }
        Ok(acc)
    };
    let mut stats: [Vec<[f64; 5]>; 3] = Default::default();
    for k in 0..3 {
        if volume_axes.contains(&k) || slice_axes.contains(&k) {
            stats[k] = (0..n[k])
                .into_par_iter()
                .map(|i| slice(k, i))
                .collect::<Result<_>>()?;
        }
    }
    let to_db = |se: f64, count: f64| 10.0 * (count / se).log10();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    // Volume metrics: PSNR over the mask; SSIM per axis, then the mean of the axes.
    let total = |k: usize| {
        stats[k].iter().fold([0.0; 5], |mut s, a| {
            s.iter_mut().zip(a).for_each(|(s, a)| *s += a);
            s
        })
    };
    let first = total(volume_axes[0]);
    let (se, count) = (first[0], first[2]);
    let (mut ssim, mut ssim_crop) = (Vec::new(), Vec::new());
    for &k in &volume_axes {
        let sum = total(k);
        ssim.push(sum[1] / sum[2]);
        if sum[4] > 0.0 {
            ssim_crop.push(sum[3] / sum[4]);
        }
    }
    // Slice metrics over the slices holding a mask pixel.
    let (mut psnr_sum, mut ssim_sum, mut lpips_sum, mut used) = (0.0, 0.0, 0.0, 0usize);
    for &axis in slice_axes {
        let scored: Vec<usize> = (0..n[axis]).filter(|&i| stats[axis][i][2] > 0.0).collect();
        for &i in &scored {
            let a = stats[axis][i];
            psnr_sum += if a[0] > 0.0 {
                to_db(a[0], a[2]).min(PSNR_CAP)
            } else {
                PSNR_CAP
            };
            ssim_sum += a[1] / a[2];
        }
        if let Some((net, _)) = eval.lpips.as_deref() {
            lpips_sum += lpips_of(net, &p, &t, axis, &scored)?;
        }
        used += scored.len();
    }
    let nf = used as f64;
    Ok(Scores {
        psnr: if se > 0.0 {
            to_db(se, count)
        } else {
            f64::INFINITY
        },
        ssim: mean(&ssim),
        ssim_skimage: if ssim_crop.is_empty() {
            f64::NAN
        } else {
            mean(&ssim_crop)
        },
        psnr_slices: psnr_sum / nf,
        ssim_slices: ssim_sum / nf,
        lpips: eval.lpips.as_ref().map(|_| lpips_sum / nf),
        slices: used,
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

/// PSNR of `pred` against `truth` over `mask`'s voxels, peak the reference's maximum, summed
/// plainly in f64: the independent value the masked scores are tested against.
#[cfg(test)]
pub(crate) fn psnr_in_by_hand(
    pred: ArrayView3<f32>,
    truth: ArrayView3<f32>,
    mask: &Array3<bool>,
) -> f64 {
    let peak = truth.fold(0.0f32, |a, &b| a.max(b)) as f64;
    let (mut se, mut n) = (0.0f64, 0.0f64);
    ndarray::Zip::from(&pred)
        .and(&truth)
        .and(mask)
        .for_each(|&p, &t, &m| {
            if m {
                se += ((p as f64 - t as f64) / peak).powi(2);
                n += 1.0;
            }
        });
    10.0 * (n / se).log10()
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
        let same = score(truth.view(), truth.view(), &eval, None).unwrap();
        assert_eq!(same.slices, 8, "the four empty axial slices are left out");
        assert_eq!(same.psnr_slices, PSNR_CAP);
        assert!((same.ssim_slices - 1.0).abs() < 1e-12);
        assert!(same.lpips.is_none());
        // A uniform error of 0.1 (after normalisation by the peak 2) on the occupied slices:
        // each slice's PSNR is 20 dB; the volume's counts the error-free empty slices too.
        let pred = truth.mapv(|v| if v > 0.0 { v + 0.2 } else { 0.0 });
        let s = score(pred.view(), truth.view(), &eval, None).unwrap();
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
                roi: None,
            },
            lpips: None,
        };
        assert_eq!(
            score(pred.view(), truth.view(), &all, None).unwrap().slices,
            3 * 8
        );
        let e = score(pred.view(), Array3::zeros((2, 2, 2)).view(), &eval, None);
        assert!(e.is_err());
    }

    #[test]
    fn a_full_mask_scores_as_the_whole_grid_and_errors_outside_it_do_not_count() {
        // No all-zero slice, so the whole-grid protocol scores every slice the mask path does.
        let truth = Array3::from_shape_fn((12, 14, 16), |(z, y, x)| {
            1.0 + ((z * 7 + y * 3 + x) % 5) as f32 * 0.2
        });
        let pred = Array3::from_shape_fn(truth.dim(), |(z, y, x)| {
            truth[[z, y, x]] + ((z + 2 * y + 3 * x) % 7) as f32 * 0.01 - 0.03
        });
        let eval = Evaluation::default();
        let whole = score(pred.view(), truth.view(), &eval, None).unwrap();
        let full = Roi {
            mask: Array3::from_elem(truth.dim(), true),
            spec: RoiSpec::default(),
        };
        let inside = score(pred.view(), truth.view(), &eval, Some(&full)).unwrap();
        for (a, b) in [
            (whole.psnr, inside.psnr),
            (whole.ssim, inside.ssim),
            (whole.ssim_skimage, inside.ssim_skimage),
            (whole.psnr_slices, inside.psnr_slices),
            (whole.ssim_slices, inside.ssim_slices),
        ] {
            assert!((a - b).abs() < 1e-9, "{a} vs {b}");
        }
        assert_eq!(whole.slices, inside.slices);
        // A box mask: a large error outside it leaves the ROI's PSNR at its closed form.
        let mut mask = Array3::from_elem(truth.dim(), false);
        mask.slice_mut(ndarray::s![2..10, 3..11, 4..12]).fill(true);
        let mut off = pred.clone();
        ndarray::Zip::from(&mut off).and(&mask).for_each(|v, &m| {
            if !m {
                *v += 5.0
            }
        });
        let boxed = Roi {
            mask: mask.clone(),
            spec: RoiSpec::default(),
        };
        let s = score(off.view(), truth.view(), &eval, Some(&boxed)).unwrap();
        let want = psnr_in_by_hand(pred.view(), truth.view(), &mask);
        assert!((s.psnr - want).abs() < 1e-4, "{} vs {want}", s.psnr);
        assert_eq!(s.slices, 8, "axial slices holding the mask");
        assert!(s.ssim > 0.0 && s.ssim <= 1.0);
        // A mask on another grid is an error naming it.
        let wrong = Roi {
            mask: Array3::from_elem((2, 2, 2), true),
            spec: RoiSpec::default(),
        };
        let e = score(pred.view(), truth.view(), &eval, Some(&wrong)).unwrap_err();
        assert!(e.to_string().contains("roi"), "{e}");
    }
}
