//! The region a volume is scored in: the object found in the references, not the air around it
//! (nor, with an erosion, a sample tube's wall or the object's partial-volume outline); or the
//! complete-data region, the voxels every view of the scan sees (`region: field_of_view`).
//!
//! The object mask (`region: object`, the default) is made once per scene, per axial slice
//! (constant z), from every channel's reference:
//! 1. each channel divided by its own maximum, then averaged over the channels (one mask for all);
//! 2. smoothed in-plane by a Gaussian of σ = `smooth_mm` (none at 0; a noisy reference needs it);
//! 3. thresholded at `threshold` × the smoothed mean's maximum over the volume;
//! 4. holes filled: background not connected (4-neighbours) to the slice's border joins the object
//!    (a tooth's pulp, the lungs of a chest);
//! 5. eroded by a disc of radius `erode_mm`.
//!
//! The field-of-view mask is [`crate::projector::seen_by_every_view`] of the scene's geometry,
//! eroded as step 5; `threshold` and `smooth_mm` do not apply to it.
//!
//! Lengths are in the scene's unit (mm; detector pixels for scenes imported in pixel units).
//! Metrics restricted to the mask are in `prism_recon::evaluate::protocol` (`docs/metrics.md`).

use crate::error::ensure_finite;
use crate::geometry::Geometry;
use crate::{Error, Result};
use ndarray::{Array2, Array3, ArrayView2, ArrayView4, Axis};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Which region is scored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Region {
    /// The object found in the references (module docs, steps 1–5).
    #[default]
    Object,
    /// The voxels every view of the scene sees: where the data determine the volume. Outside
    /// it (a fan beam's grid corners on a full turn) each voxel is a limited-angle problem whose
    /// values the regulariser and the solver decide as much as the scan.
    FieldOfView,
}

/// How the mask is made (YAML `evaluation.roi`; every field optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoiSpec {
    /// The object (default) or the complete-data region.
    pub region: Region,
    /// Fraction of the smoothed references' maximum above which a pixel is object, in (0, 1).
    pub threshold: f64,
    /// Gaussian σ of the in-plane smoothing before the threshold, mm (0: none).
    pub smooth_mm: f64,
    /// Radius of the disc the filled object is eroded by, mm (0: none).
    pub erode_mm: f64,
}

impl Default for RoiSpec {
    fn default() -> Self {
        RoiSpec {
            region: Region::Object,
            threshold: 0.1,
            smooth_mm: 0.0,
            erode_mm: 0.0,
        }
    }
}

impl RoiSpec {
    /// How the mask is made, in words (`metrics.json`, reports).
    pub fn describe(&self) -> String {
        let eroded = if self.erode_mm > 0.0 {
            format!(", eroded by {} mm", self.erode_mm)
        } else {
            String::new()
        };
        if self.region == Region::FieldOfView {
            return format!("field of view: the voxels every view sees{eroded}");
        }
        format!(
            "object mask: the channels' mean reference{} above {} of its maximum, holes filled{}",
            if self.smooth_mm > 0.0 {
                format!(" smoothed (σ {} mm)", self.smooth_mm)
            } else {
                String::new()
            },
            self.threshold,
            eroded
        )
    }

    /// Check every field; errors name it (`threshold`, `smooth_mm`, `erode_mm`).
    pub fn validate(&self) -> Result<()> {
        if self.region == Region::FieldOfView {
            let default = RoiSpec::default();
            for (name, set) in [
                ("threshold", self.threshold != default.threshold),
                ("smooth_mm", self.smooth_mm != default.smooth_mm),
            ] {
                if set {
                    return Err(Error::invalid(
                        name,
                        "applies to `region: object` only (the field of view is made from the \
                         geometry, not the references)",
                    ));
                }
            }
        }
        if !(self.threshold > 0.0 && self.threshold < 1.0) {
            return Err(Error::invalid(
                "threshold",
                format!("must lie in (0, 1) (got {})", self.threshold),
            ));
        }
        for (name, v) in [("smooth_mm", self.smooth_mm), ("erode_mm", self.erode_mm)] {
            ensure_finite(name, v)?;
            if v < 0.0 {
                return Err(Error::invalid(name, format!("must be ≥ 0 (got {v})")));
            }
        }
        Ok(())
    }
}

/// An object mask, `[z][y][x]`, true inside the region scored.
#[derive(Clone, Debug, PartialEq)]
pub struct Roi {
    pub mask: Array3<bool>,
    pub spec: RoiSpec,
}

impl Roi {
    /// The region `spec.region` names for a scene with `references` (`[channel][z][y][x]`) on
    /// `geometry`: the object mask of the references, or the voxels every view sees.
    pub fn new(references: ArrayView4<f32>, geometry: &Geometry, spec: &RoiSpec) -> Result<Roi> {
        let g = &geometry.volume;
        match spec.region {
            Region::Object => Roi::from_references(references, g.dy, g.dx, spec),
            Region::FieldOfView => Roi::from_field_of_view(geometry, spec),
        }
    }

    /// The mask of `references` (`[channel][z][y][x]`, on voxels of in-plane size `dy`, `dx`
    /// mm) under `spec` (module docs). An empty mask is an error naming `threshold`.
    pub fn from_references(
        references: ArrayView4<f32>,
        dy: f64,
        dx: f64,
        spec: &RoiSpec,
    ) -> Result<Roi> {
        spec.validate()?;
        if spec.region != Region::Object {
            return Err(Error::invalid(
                "region",
                "the mask from the references is `region: object`",
            ));
        }
        let (channels, nz, ny, nx) = references.dim();
        if channels == 0 || nz * ny * nx == 0 {
            return Err(Error::invalid("references", "are empty"));
        }
        let mut mean = Array3::<f64>::zeros((nz, ny, nx));
        for c in references.axis_iter(Axis(0)) {
            let peak = c.fold(0.0f32, |a, &b| a.max(b));
            if peak <= 0.0 {
                return Err(Error::invalid(
                    "references",
                    "a channel's reference has no positive value",
                ));
            }
            mean.zip_mut_with(&c, |m, &v| *m += v as f64 / peak as f64 / channels as f64);
        }
        let smoothed: Vec<Array2<f64>> = mean
            .axis_iter(Axis(0))
            .map(|s| smooth(s, spec.smooth_mm / dy, spec.smooth_mm / dx))
            .collect();
        let peak = smoothed
            .iter()
            .flat_map(|s| s.iter())
            .fold(0.0f64, |a, &b| a.max(b));
        let level = spec.threshold * peak;
        let mut mask = Array3::from_elem((nz, ny, nx), false);
        for (z, s) in smoothed.iter().enumerate() {
            let object = fill_holes(&s.mapv(|v| v > level));
            let object = erode(&object, spec.erode_mm / dy, spec.erode_mm / dx);
            mask.index_axis_mut(Axis(0), z).assign(&object);
        }
        Roi::non_empty(mask, spec, "threshold", || {
            format!(
                "the region of interest is empty (threshold {}, erosion {} mm): lower the \
                 threshold or the erosion",
                spec.threshold, spec.erode_mm
            )
        })
    }

    /// The voxels every view of `geometry` sees, each slice eroded by `spec.erode_mm`
    /// (`spec.region` must be [`Region::FieldOfView`]). An empty region is an error naming
    /// `region`.
    pub fn from_field_of_view(geometry: &Geometry, spec: &RoiSpec) -> Result<Roi> {
        spec.validate()?;
        if spec.region != Region::FieldOfView {
            return Err(Error::invalid(
                "region",
                "the mask from the geometry is `region: field_of_view`",
            ));
        }
        let g = &geometry.volume;
        let mut mask = crate::projector::seen_by_every_view(geometry)?;
        for mut slice in mask.axis_iter_mut(Axis(0)) {
            let eroded = erode(
                &slice.to_owned(),
                spec.erode_mm / g.dy,
                spec.erode_mm / g.dx,
            );
            slice.assign(&eroded);
        }
        Roi::non_empty(mask, spec, "region", || {
            format!(
                "no voxel is seen by every view (erosion {} mm): the grid lies outside the \
                 scan's complete field of view; score the object instead",
                spec.erode_mm
            )
        })
    }

    /// The region of `mask` under `spec`, or an error naming `field` with `why` when it holds
    /// no voxel.
    fn non_empty(
        mask: Array3<bool>,
        spec: &RoiSpec,
        field: &str,
        why: impl FnOnce() -> String,
    ) -> Result<Roi> {
        let roi = Roi {
            mask,
            spec: spec.clone(),
        };
        if roi.voxels() == 0 {
            return Err(Error::invalid(field, why()));
        }
        Ok(roi)
    }

    /// Voxels inside the region.
    pub fn voxels(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }

    /// One line for `metrics.json`: how the mask was made and how much of the grid it holds.
    pub fn describe(&self) -> String {
        format!(
            "{}; {} of {} voxels ({:.1} %)",
            self.spec.describe(),
            self.voxels(),
            self.mask.len(),
            100.0 * self.voxels() as f64 / self.mask.len() as f64
        )
    }
}

/// `img` smoothed by a separable Gaussian of σ `sy`, `sx` pixels (radius 3σ, the border
/// pixel repeated); a σ below 0.1 pixel leaves that axis as is.
fn smooth(img: ArrayView2<f64>, sy: f64, sx: f64) -> Array2<f64> {
    let along = |img: &Array2<f64>, axis: usize, sigma: f64| -> Array2<f64> {
        if sigma < 0.1 {
            return img.clone();
        }
        let r = (3.0 * sigma).ceil() as isize;
        let w: Vec<f64> = (-r..=r)
            .map(|d| (-0.5 * (d as f64 / sigma).powi(2)).exp())
            .collect();
        let total: f64 = w.iter().sum();
        let n = img.shape()[axis] as isize;
        Array2::from_shape_fn(img.dim(), |(i, j)| {
            let at = if axis == 0 { i } else { j } as isize;
            w.iter()
                .zip(-r..=r)
                .map(|(wk, d)| {
                    let k = (at + d).clamp(0, n - 1) as usize;
                    wk * if axis == 0 { img[[k, j]] } else { img[[i, k]] }
                })
                .sum::<f64>()
                / total
        })
    };
    along(&along(&img.to_owned(), 0, sy), 1, sx)
}

/// `object` with every background pixel not 4-connected to the image border turned object.
fn fill_holes(object: &Array2<bool>) -> Array2<bool> {
    let (h, w) = object.dim();
    let mut outside = Array2::from_elem((h, w), false);
    let mut queue = VecDeque::new();
    let visit = |i: usize, j: usize, outside: &mut Array2<bool>, q: &mut VecDeque<_>| {
        if !object[[i, j]] && !outside[[i, j]] {
            outside[[i, j]] = true;
            q.push_back((i, j));
        }
    };
    for i in 0..h {
        visit(i, 0, &mut outside, &mut queue);
        visit(i, w - 1, &mut outside, &mut queue);
    }
    for j in 0..w {
        visit(0, j, &mut outside, &mut queue);
        visit(h - 1, j, &mut outside, &mut queue);
    }
    while let Some((i, j)) = queue.pop_front() {
        if i > 0 {
            visit(i - 1, j, &mut outside, &mut queue);
        }
        if i + 1 < h {
            visit(i + 1, j, &mut outside, &mut queue);
        }
        if j > 0 {
            visit(i, j - 1, &mut outside, &mut queue);
        }
        if j + 1 < w {
            visit(i, j + 1, &mut outside, &mut queue);
        }
    }
    outside.mapv(|o| !o)
}

/// `object` eroded by the ellipse of semi-axes `ry`, `rx` pixels (a disc in mm): a pixel stays
/// when every pixel of the ellipse around it is object (outside the image counts as object, so
/// the border of the grid does not erode).
fn erode(object: &Array2<bool>, ry: f64, rx: f64) -> Array2<bool> {
    if ry < 0.5 && rx < 0.5 {
        return object.clone();
    }
    let (h, w) = object.dim();
    let (iy, ix) = (ry.floor() as isize, rx.floor() as isize);
    let offsets: Vec<(isize, isize)> = (-iy..=iy)
        .flat_map(|dy| (-ix..=ix).map(move |dx| (dy, dx)))
        .filter(|&(dy, dx)| {
            let e = |d: isize, r: f64| if r > 0.0 { (d as f64 / r).powi(2) } else { 0.0 };
            e(dy, ry) + e(dx, rx) <= 1.0
        })
        .collect();
    Array2::from_shape_fn((h, w), |(i, j)| {
        object[[i, j]]
            && offsets.iter().all(|&(dy, dx)| {
                let (y, x) = (i as isize + dy, j as isize + dx);
                y < 0
                    || x < 0
                    || y >= h as isize
                    || x >= w as isize
                    || object[[y as usize, x as usize]]
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array4;

    /// A disc of radius `r` (pixels) of value `inside`, a ring (a tube's wall) from `r + 2` to
    /// `r + 4`, and a hole of radius 3 at the centre, on an `n × n` slice.
    fn tube(n: usize, r: f64) -> Array4<f32> {
        let c = n as f64 / 2.0 - 0.5;
        Array4::from_shape_fn((2, 1, n, n), |(ch, _, i, j)| {
            let d = ((i as f64 - c).powi(2) + (j as f64 - c).powi(2)).sqrt();
            let v = if d < 3.0 {
                0.0
            } else if d < r {
                1.0
            } else if (r + 2.0..r + 4.0).contains(&d) {
                2.0
            } else {
                0.0
            };
            v * (ch + 1) as f32
        })
    }

    fn count(r: &Roi) -> usize {
        r.voxels()
    }

    #[test]
    fn holes_are_filled_and_the_tube_is_eroded_away() {
        let refs = tube(64, 20.0);
        let spec = RoiSpec {
            threshold: 0.2,
            ..RoiSpec::default()
        };
        let roi = Roi::from_references(refs.view(), 0.5, 0.5, &spec).unwrap();
        // Filled: the disc of radius r + 4 (the gap between object and wall is a hole too).
        let filled = count(&roi);
        let area = |r: f64| std::f64::consts::PI * r * r;
        assert!(
            (filled as f64 - area(24.0)).abs() < 0.03 * area(24.0),
            "{filled}"
        );
        assert!(roi.mask[[0, 32, 32]], "the central hole is filled");
        // Eroded by 2.5 mm = 5 pixels: the disc of radius 19 remains.
        let eroded = Roi::from_references(
            refs.view(),
            0.5,
            0.5,
            &RoiSpec {
                erode_mm: 2.5,
                ..spec.clone()
            },
        )
        .unwrap();
        assert!((count(&eroded) as f64 - area(19.0)).abs() < 0.05 * area(19.0));
        assert!(!eroded.mask[[0, 32, 32 + 21]], "the tube's wall is out");
    }

    #[test]
    fn smoothing_keeps_noise_out_of_the_mask() {
        // Alternating ±0.3 speckle in air beside a solid square: thresholded raw, half the
        // speckle is object; smoothed over 2 pixels it averages to 0.
        let refs = Array4::from_shape_fn((1, 1, 48, 48), |(_, _, i, j)| {
            if (16..32).contains(&i) && (16..32).contains(&j) {
                1.0
            } else if (i + j) % 2 == 0 {
                0.3
            } else {
                -0.3
            }
        });
        let raw = RoiSpec {
            threshold: 0.25,
            ..RoiSpec::default()
        };
        let noisy = Roi::from_references(refs.view(), 1.0, 1.0, &raw).unwrap();
        assert!(count(&noisy) > 16 * 16 + 500);
        let smooth = RoiSpec {
            smooth_mm: 2.0,
            ..raw
        };
        let clean = Roi::from_references(refs.view(), 1.0, 1.0, &smooth).unwrap();
        // The square (256 pixels) grows by the blur: its 0.25 level lies 0.67σ ≈ 1.3 pixels out.
        assert!(
            (256..400).contains(&count(&clean)),
            "{} voxels",
            count(&clean)
        );
        assert!(!clean.mask[[0, 2, 2]]);
    }

    #[test]
    fn bad_specs_and_empty_masks_are_errors_naming_the_field() {
        let refs = tube(32, 8.0);
        let bad = RoiSpec {
            threshold: 1.5,
            ..RoiSpec::default()
        };
        let e = Roi::from_references(refs.view(), 1.0, 1.0, &bad).unwrap_err();
        assert!(e.to_string().contains("threshold"), "{e}");
        let e = Roi::from_references(
            refs.view(),
            1.0,
            1.0,
            &RoiSpec {
                erode_mm: -1.0,
                ..RoiSpec::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("erode_mm"), "{e}");
        let e = Roi::from_references(
            refs.view(),
            1.0,
            1.0,
            &RoiSpec {
                erode_mm: 40.0,
                ..RoiSpec::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("empty"), "{e}");
    }

    #[test]
    fn the_field_of_view_region_comes_from_the_geometry_and_refuses_object_settings() {
        use crate::geometry::{Beam, Detector, VolumeGrid};
        // Parallel beam, 8 columns of 1 mm, views at 0 and 90° over a 16 mm grid of one slice:
        // every view sees |x| ≤ 4 and |y| ≤ 4 mm, an 8 × 8 square.
        let g = Geometry {
            beam: Beam::Parallel,
            dso: 100.0,
            dsd: 200.0,
            detector: Detector {
                rows: 1,
                cols: 8,
                pitch_u: 1.0,
                pitch_v: 1.0,
                offset_u: 0.0,
                offset_v: 0.0,
            },
            volume: VolumeGrid {
                nz: 1,
                ..VolumeGrid::cube(16, 1.0)
            },
            angles_rad: vec![0.0, std::f64::consts::FRAC_PI_2],
            vectors: None,
        };
        let fov = RoiSpec {
            region: Region::FieldOfView,
            ..RoiSpec::default()
        };
        let roi = Roi::from_field_of_view(&g, &fov).unwrap();
        assert_eq!(count(&roi), 64);
        assert!(
            roi.describe()
                .starts_with("field of view: the voxels every view sees; 64 of 256")
        );
        // Eroded by 1.2 mm (the grid's border does not erode; the square's edge does): 6 × 6.
        let eroded = RoiSpec {
            erode_mm: 1.2,
            ..fov.clone()
        };
        assert_eq!(count(&Roi::from_field_of_view(&g, &eroded).unwrap()), 36);
        // Object settings are refused, naming the field; each constructor refuses the other region.
        let e = Roi::from_field_of_view(
            &g,
            &RoiSpec {
                threshold: 0.3,
                ..fov.clone()
            },
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("threshold") && e.to_string().contains("object"),
            "{e}"
        );
        let e = Roi::from_field_of_view(&g, &RoiSpec::default()).unwrap_err();
        assert!(e.to_string().contains("region"), "{e}");
        let refs = tube(16, 4.0);
        let e = Roi::from_references(refs.view(), 1.0, 1.0, &fov).unwrap_err();
        assert!(e.to_string().contains("region"), "{e}");
        // A grid no view sees whole: an error naming `region`.
        let far = Geometry {
            angles_rad: vec![0.0, std::f64::consts::FRAC_PI_2],
            volume: VolumeGrid {
                offset: [40.0, 40.0, 0.0],
                ..g.volume.clone()
            },
            ..g.clone()
        };
        let e = Roi::from_field_of_view(&far, &fov).unwrap_err();
        assert!(e.to_string().contains("region"), "{e}");
    }
}
