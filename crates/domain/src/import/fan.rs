//! 2-D fan beams (an import config's `fan:` fields): flat detector lines, and curved
//! (equiangular) ones rebinned onto a flat line at import.
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
use serde::Deserialize;

use crate::geometry::{Beam, Detector, Geometry, VolumeGrid};
use crate::{Error, Result};

/// A fan beam on a flat detector line (or a curved one, rebinned onto it), reconstructing one
/// slice: exactly the middle row of a cone beam, so the scene stores it as a one-row cone beam
/// over a one-voxel-thick volume (every ray lies in the plane z = 0, through the voxel centres).
/// The row's height is `pitch` and the slice is as thick as the row seen at the axis
/// (`pitch · dso / dsd`); neither changes a line integral.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FanGeometry {
    /// Source → rotation axis and source → detector distances, mm.
    pub dso: f64,
    pub dsd: f64,
    /// Detector columns, their pitch (mm) and the shift of the detector centre along u (mm): a
    /// rotation axis projecting `k` columns right of the centre is `offset_u = k·pitch`.
    pub cols: usize,
    pub pitch: f64,
    #[serde(default)]
    pub offset_u: f64,
    /// The slice: voxel counts and sizes (mm) along x and y, its centre (x, y) in mm.
    pub nx: usize,
    pub ny: usize,
    pub dx: f64,
    pub dy: f64,
    #[serde(default)]
    pub offset: [f64; 2],
    /// `flat` (the default): the columns on a straight line. `curved`: on the arc of radius `dsd`
    /// around the source, equally spaced in fan angle, `pitch` and `offset_u` then being arc
    /// lengths at `dsd`; the import rebins them onto the flat line the same rays cross
    /// ([`Rebinning`]), so the scene holds a flat detector.
    #[serde(default)]
    pub detector: FanDetector,
}

/// The shape of a fan beam's detector line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FanDetector {
    #[default]
    Flat,
    /// Equiangular columns on an arc centred on the source (third-generation CT scanners).
    Curved,
}

impl FanGeometry {
    /// How the measured columns become the scene's flat ones: `None` for a flat detector.
    pub fn rebinning(&self) -> Result<Option<Rebinning>> {
        match self.detector {
            FanDetector::Flat => Ok(None),
            FanDetector::Curved => {
                Rebinning::new(self.dsd, self.cols, self.pitch, self.offset_u).map(Some)
            }
        }
    }

    /// The equivalent one-row cone-beam geometry with `angles_rad` (a curved detector's flat
    /// line after rebinning).
    pub fn to_geometry(&self, angles_rad: Vec<f64>) -> Result<Geometry> {
        let (cols, offset_u) = match self.rebinning()? {
            Some(r) => (r.flat_cols, r.flat_offset_u),
            None => (self.cols, self.offset_u),
        };
        let g = Geometry {
            beam: Beam::Cone,
            dso: self.dso,
            dsd: self.dsd,
            detector: Detector {
                rows: 1,
                cols,
                pitch_u: self.pitch,
                pitch_v: self.pitch,
                offset_u,
                offset_v: 0.0,
            },
            volume: VolumeGrid {
                nx: self.nx,
                ny: self.ny,
                nz: 1,
                dx: self.dx,
                dy: self.dy,
                dz: self.pitch * self.dso / self.dsd,
                offset: [self.offset[0], self.offset[1], 0.0],
            },
            angles_rad,
            vectors: None,
        };
        // Errors name the fan's own fields, not the cone fields they became.
        g.validate().map_err(|e| match e {
            Error::Invalid { field, message } => {
                let name = field
                    .trim_start_matches("detector.")
                    .trim_start_matches("volume.");
                let name = match name {
                    "pitch_u" | "pitch_v" | "dz" => "pitch",
                    other => other,
                };
                Error::invalid(name, message)
            }
            other => other,
        })?;
        Ok(g)
    }
}

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
