//! Analytic spectral phantoms: sums of ellipsoids that carry additive material fractions.
//!
//! A material fraction is the volume fraction of the material at its nominal density (the
//! density of the NIST table), so a voxel's attenuation is `μ(E) = Σₘ fₘ·μₘ(E)`. Components add,
//! Shepp–Logan style: an insert carries the *difference* to what surrounds it, e.g. a fat region
//! inside water is `water −1, adipose +1`, an iodine vial in water is `iodine +0.002`.

use super::ellipsoid::{Ellipsoid, UnitMap};
use crate::geometry::{Geometry, VolumeGrid};
use crate::physics::Material;
use crate::{Error, Result};
use ndarray::Array3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Density of pure (solid) iodine in the NIST table, g/cm³: a concentration of `c` mg/mL is the
/// iodine fraction `c / 4930`.
pub const IODINE_DENSITY_MG_ML: f64 = 4930.0;
/// Density of pure calcium in the NIST table, g/cm³ × 1000 (mg/mL).
pub const CALCIUM_DENSITY_MG_ML: f64 = 1550.0;

/// Iodine fraction of a solution of `mg_per_ml` mg of iodine per mL.
pub fn iodine_fraction(mg_per_ml: f64) -> f64 {
    mg_per_ml / IODINE_DENSITY_MG_ML
}

/// One ellipsoid and the material fractions it adds inside itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Component {
    /// Free-form name shown in errors and listings ("spine", "iodine 5 mg/mL").
    #[serde(default)]
    pub label: String,
    pub ellipsoid: Ellipsoid,
    /// Additive fraction deltas, e.g. `[[water, -1.0], [adipose, 1.0]]`.
    pub materials: Vec<(Material, f64)>,
}

impl Component {
    /// A component from its parts.
    pub fn new(label: &str, ellipsoid: Ellipsoid, materials: &[(Material, f64)]) -> Self {
        Component {
            label: label.to_string(),
            ellipsoid,
            materials: materials.to_vec(),
        }
    }

    /// Check the ellipsoid and that every fraction is finite.
    pub fn validate(&self) -> Result<()> {
        self.ellipsoid
            .validate()
            .map_err(|e| e.under("ellipsoid"))?;
        if self.materials.is_empty() {
            return Err(Error::invalid("materials", "the list is empty"));
        }
        for (i, (m, f)) in self.materials.iter().enumerate() {
            if !f.is_finite() {
                return Err(Error::invalid(
                    format!("materials[{i}]"),
                    format!("fraction of {} must be finite (got {f})", m.name()),
                ));
            }
        }
        Ok(())
    }
}

/// An analytic phantom: the fraction of material m at a point is the sum of the deltas of m over
/// the components that contain the point.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpectralPhantom {
    pub ellipsoids: Vec<Component>,
}

/// Per-material arrays, in [`Material::ALL`] order.
pub type MaterialVolumes = Vec<(Material, Array3<f32>)>;

impl SpectralPhantom {
    /// Check every component; errors name it (`ellipsoids[3].ellipsoid.semi_axes[0]`).
    pub fn validate(&self) -> Result<()> {
        if self.ellipsoids.is_empty() {
            return Err(Error::invalid("ellipsoids", "the phantom has no component"));
        }
        for (i, c) in self.ellipsoids.iter().enumerate() {
            c.validate()
                .map_err(|e| e.under(&format!("ellipsoids[{i}]")))?;
        }
        Ok(())
    }

    /// The materials the phantom uses, in [`Material::ALL`] order.
    pub fn materials(&self) -> Vec<Material> {
        Material::ALL
            .into_iter()
            .filter(|m| {
                self.ellipsoids
                    .iter()
                    .any(|c| c.materials.iter().any(|(n, _)| n == m))
            })
            .collect()
    }

    /// Axis-aligned box (min, max corners, mm) that holds every component.
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for c in &self.ellipsoids {
            let (a, b) = c.ellipsoid.bounding_box();
            for k in 0..3 {
                lo[k] = lo[k].min(a[k]);
                hi[k] = hi[k].max(b[k]);
            }
        }
        (lo, hi)
    }

    /// Material fractions at world point `p`, one per entry of [`Self::materials`].
    pub fn fractions_at(&self, p: [f64; 3]) -> Vec<(Material, f64)> {
        let prepared = Prepared::new(self);
        let mut out = vec![0.0; prepared.materials.len()];
        for (map, deltas) in prepared.maps.iter().zip(&prepared.deltas) {
            if map.level(p) <= 1.0 {
                for &(k, f) in deltas {
                    out[k] += f;
                }
            }
        }
        prepared.materials.into_iter().zip(out).collect()
    }

    /// Exact line integral (mm) of each material's fraction along every pixel ray of `geometry`,
    /// `[view][row][col]`: `Σ_components delta · chord`, closed form (see [`Ellipsoid::chord`]).
    pub fn material_paths(&self, geometry: &Geometry) -> Result<MaterialVolumes> {
        self.validate()?;
        geometry.validate().map_err(|e| e.under("geometry"))?;
        let prepared = Prepared::new(self);
        let nm = prepared.materials.len();
        let (views, rows, cols) = (
            geometry.views(),
            geometry.detector.rows,
            geometry.detector.cols,
        );
        let cameras = geometry.cameras();
        // One chunk per (view, row): `nm × cols` values, material-major.
        let mut buf = vec![0.0f32; views * rows * nm * cols];
        buf.par_chunks_mut(nm * cols)
            .enumerate()
            .for_each(|(vr, chunk)| {
                let (view, row) = (vr / rows, vr % rows);
                let camera = &cameras[view];
                let mut acc = vec![0.0f64; nm];
                for col in 0..cols {
                    let ray = camera.pixel_ray(col as f64, row as f64);
                    acc.fill(0.0);
                    for (map, deltas) in prepared.maps.iter().zip(&prepared.deltas) {
                        let chord = map.chord(ray.origin, ray.direction, ray.length);
                        if chord > 0.0 {
                            for &(k, f) in deltas {
                                acc[k] += f * chord;
                            }
                        }
                    }
                    for (k, a) in acc.iter().enumerate() {
                        chunk[k * cols + col] = *a as f32;
                    }
                }
            });
        Ok(prepared
            .materials
            .iter()
            .enumerate()
            .map(|(k, &m)| {
                let arr = Array3::from_shape_fn((views, rows, cols), |(v, r, c)| {
                    buf[((v * rows + r) * nm + k) * cols + c]
                });
                (m, arr)
            })
            .collect())
    }

    /// Material fraction volumes `[z][y][x]` on `grid`, each voxel the mean of `supersample³`
    /// point samples at the centres of a regular sub-grid (partial volume). A voxel whose eight
    /// corners lie inside a component gets that component's full delta exactly (ellipsoids are
    /// convex); a voxel outside its bounding box gets nothing.
    pub fn fractions(&self, grid: &VolumeGrid, supersample: usize) -> Result<MaterialVolumes> {
        self.validate()?;
        grid.validate().map_err(|e| e.under("grid"))?;
        if !(1..=64).contains(&supersample) {
            return Err(Error::invalid(
                "supersample",
                format!("must be in 1..=64 (got {supersample})"),
            ));
        }
        let prepared = Prepared::new(self);
        let boxes: Vec<_> = self
            .ellipsoids
            .iter()
            .map(|c| c.ellipsoid.bounding_box())
            .collect();
        let nm = prepared.materials.len();
        let (nx, ny, nz) = (grid.nx, grid.ny, grid.nz);
        let d = grid.voxel_size();
        let s = supersample;
        let inv = 1.0 / (s * s * s) as f64;
        let sub: Vec<f64> = (0..s).map(|k| (k as f64 + 0.5) / s as f64 - 0.5).collect();
        // One chunk per (z, y) line: `nm × nx` values, material-major.
        let mut buf = vec![0.0f32; nz * ny * nm * nx];
        buf.par_chunks_mut(nm * nx)
            .enumerate()
            .for_each(|(zy, chunk)| {
                let (iz, iy) = (zy / ny, zy % ny);
                let mut acc = vec![0.0f64; nm];
                for ix in 0..nx {
                    let c = grid.voxel_centre(ix, iy, iz);
                    let vlo = [c[0] - d[0] / 2.0, c[1] - d[1] / 2.0, c[2] - d[2] / 2.0];
                    let vhi = [c[0] + d[0] / 2.0, c[1] + d[1] / 2.0, c[2] + d[2] / 2.0];
                    acc.fill(0.0);
                    for ((map, deltas), (blo, bhi)) in
                        prepared.maps.iter().zip(&prepared.deltas).zip(&boxes)
                    {
                        if (0..3).any(|k| vhi[k] < blo[k] || vlo[k] > bhi[k]) {
                            continue;
                        }
                        let corners_inside = (0..8).all(|b| {
                            let p = [
                                if b & 1 == 0 { vlo[0] } else { vhi[0] },
                                if b & 2 == 0 { vlo[1] } else { vhi[1] },
                                if b & 4 == 0 { vlo[2] } else { vhi[2] },
                            ];
                            map.level(p) <= 1.0
                        });
                        let share = if corners_inside {
                            1.0
                        } else {
                            let mut inside = 0usize;
                            for oz in &sub {
                                for oy in &sub {
                                    for ox in &sub {
                                        let p =
                                            [c[0] + ox * d[0], c[1] + oy * d[1], c[2] + oz * d[2]];
                                        inside += usize::from(map.level(p) <= 1.0);
                                    }
                                }
                            }
                            inside as f64 * inv
                        };
                        if share > 0.0 {
                            for &(k, f) in deltas {
                                acc[k] += f * share;
                            }
                        }
                    }
                    for (k, a) in acc.iter().enumerate() {
                        chunk[k * nx + ix] = *a as f32;
                    }
                }
            });
        Ok(prepared
            .materials
            .iter()
            .enumerate()
            .map(|(k, &m)| {
                let arr = Array3::from_shape_fn((nz, ny, nx), |(z, y, x)| {
                    buf[((z * ny + y) * nm + k) * nx + x]
                });
                (m, arr)
            })
            .collect())
    }
}

/// Unit-sphere maps and deltas indexed by position in `materials`, built once per call.
struct Prepared {
    materials: Vec<Material>,
    maps: Vec<UnitMap>,
    deltas: Vec<Vec<(usize, f64)>>,
}

impl Prepared {
    fn new(phantom: &SpectralPhantom) -> Self {
        let materials = phantom.materials();
        let index = |m: Material| materials.iter().position(|&n| n == m).unwrap_or(0);
        Prepared {
            maps: phantom
                .ellipsoids
                .iter()
                .map(|c| c.ellipsoid.unit_map())
                .collect(),
            deltas: phantom
                .ellipsoids
                .iter()
                .map(|c| c.materials.iter().map(|&(m, f)| (index(m), f)).collect())
                .collect(),
            materials,
        }
    }
}

#[cfg(test)]
mod tests;
