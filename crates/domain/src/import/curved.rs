//! Curved (equiangular) fan-beam detectors, rebinned onto a flat detector line at import.
//!
//! A curved fan detector's columns sit on the arc of radius `dsd` around the source, equally
//! spaced in fan angle: column `c` at `γ_c = ((c + ½ − cols/2)·pitch + offset_u) / dsd`, with
//! `pitch` and `offset_u` arc lengths (mm) at `dsd` and γ > 0 toward the detector's +u. Prism's
//! projectors, FDK and render ops share one camera model, the flat detector, so the import
//! resamples every view onto the flat line at `dsd` that the same rays cross: flat column `k` at
//! `u_k = dsd·tan γ` takes the measured value at γ, linearly interpolated in γ between the two
//! arc columns around it.
//!
//! The flat line's pitch is the arc pitch (the same sampling on the central ray, finer toward the
//! edges, where the arc's columns spread), and its columns span the arc's first to last column
//! centre, so nothing is extrapolated. Interpolating a line-integral profile `p(γ)` linearly costs
//! at most `Δγ²·max|p''| / 8` per value; where `p` has a kink (the edge of a sharp object) the
//! error is first order in the pitch, as it is for any resampling.

use ndarray::Array3;

use crate::{Error, Result};

/// The widest fan accepted: a ray 75° off the central ray crosses the flat line at 3.7·dsd, so a
/// wider fan would need an impractically long flat line.
pub const MAX_FAN_ANGLE_DEG: f64 = 75.0;

/// How a curved detector's columns become a flat line's.
#[derive(Clone, Debug)]
pub struct Rebinning {
    /// Columns as measured, on the arc.
    pub curved_cols: usize,
    /// Columns of the flat line, pitch equal to the arc pitch.
    pub flat_cols: usize,
    /// The flat line's centre shift along u (mm), in the flat detector's convention
    /// (`u = (k + ½ − cols/2)·pitch + offset_u`).
    pub flat_offset_u: f64,
    /// Per flat column: the arc column on the ray's lower-γ side, and the weight of the next.
    taps: Vec<(usize, f32)>,
}

impl Rebinning {
    /// The rebinning of an arc of `cols` columns of `pitch` (mm at `dsd`) shifted by `offset_u`
    /// (mm along the arc). Errors name the fan's fields: a non-positive `dsd` or `pitch`, no
    /// columns, or a fan wider than ±[`MAX_FAN_ANGLE_DEG`].
    pub fn new(dsd: f64, cols: usize, pitch: f64, offset_u: f64) -> Result<Self> {
        for (name, x) in [("dsd", dsd), ("pitch", pitch)] {
            if !(x.is_finite() && x > 0.0) {
                return Err(Error::invalid(
                    name,
                    format!("must be finite and > 0, got {x}"),
                ));
            }
        }
        if cols == 0 {
            return Err(Error::invalid("cols", "must be at least 1"));
        }
        if !offset_u.is_finite() {
            return Err(Error::invalid("offset_u", "must be finite"));
        }
        let gamma = |c: f64| ((c + 0.5 - cols as f64 / 2.0) * pitch + offset_u) / dsd;
        let (g0, g1) = (gamma(0.0), gamma((cols - 1) as f64));
        let widest = g0.abs().max(g1.abs()).to_degrees();
        if widest > MAX_FAN_ANGLE_DEG {
            return Err(Error::invalid(
                "pitch",
                format!(
                    "a curved detector of {cols} columns of {pitch} mm (arc at dsd = {dsd} mm, \
                     offset_u {offset_u} mm) reaches {widest:.1}° off the central ray; at most \
                     {MAX_FAN_ANGLE_DEG}° can be rebinned onto a flat line (are `pitch` and \
                     `offset_u` arc lengths in mm?)"
                ),
            ));
        }
        let (u0, u1) = (dsd * g0.tan(), dsd * g1.tan());
        // A tolerance of 1e-9 pitches keeps an exact fit (a single column, or a span that is a
        // whole number of pitches) from losing its last column to rounding.
        let flat_cols = ((u1 - u0) / pitch + 1e-9).floor() as usize + 1;
        let flat_offset_u = 0.5 * (u0 + u1);
        let last = (cols - 1) as f64;
        let taps = (0..flat_cols)
            .map(|k| {
                let u = (k as f64 + 0.5 - flat_cols as f64 / 2.0) * pitch + flat_offset_u;
                let t = (dsd * (u / dsd).atan() - offset_u) / pitch + cols as f64 / 2.0 - 0.5;
                let t = t.clamp(0.0, last);
                let i = (t.floor() as usize).min(cols.saturating_sub(2));
                (i, (t - i as f64) as f32)
            })
            .collect();
        Ok(Self {
            curved_cols: cols,
            flat_cols,
            flat_offset_u,
            taps,
        })
    }

    /// Images `[views, rows, curved_cols]` → `[views, rows, flat_cols]`; every row is resampled
    /// alike (a fan beam has one).
    pub fn apply(&self, p: &Array3<f32>) -> Array3<f32> {
        let (views, rows, cols) = p.dim();
        assert_eq!(cols, self.curved_cols, "images of the curved detector");
        Array3::from_shape_fn((views, rows, self.flat_cols), |(v, r, k)| {
            let (i, w) = self.taps[k];
            let a = p[[v, r, i]];
            if w == 0.0 {
                a
            } else {
                a + w * (p[[v, r, i + 1]] - a)
            }
        })
    }
}
