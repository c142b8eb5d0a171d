//! Material fraction volumes from clinical CT in Hounsfield units.
//!
//! Pipeline: [`HuVolume::load`] an int16 `.npy` stored `(z, y, x)` with its voxel size
//! `(dz, dy, dx)` → [`HuVolume::isotropic_z`] (linear interpolation along z to the in-plane
//! voxel size) → [`HuVolume::resample`] onto a target [`VolumeGrid`] (trilinear; outside the CT
//! volume is air, −1000 HU) → [`HuMapping::fractions`]. [`hu_material_volumes`] chains them.
//! The CT volume is centred on the isocentre.
//!
//! # How a fraction encodes density
//! A fraction is the volume fraction of a material at its nominal NIST density, so a voxel's
//! attenuation is `μ(E) = Σₘ fₘ·μₘ(E)`. HU is affine in the fractions,
//! `HU = 1000·(Σₘ fₘ μₘ(E₀)/μ_water(E₀) − 1)`, evaluated at the calibration energy
//! `E₀ = 70 keV` (the effective energy of the 120 kVp scans; μ from `mu_over_rho.csv`, xraydb).
//! The mapping is piecewise linear in HU between *knot* compositions, each of which has exactly
//! its knot's HU at E₀; hence every HU in range is reproduced exactly at 70 keV, and other
//! energies follow from the materials' own spectra:
//!
//! | HU | composition |
//! |---|---|
//! | ≤ −998.9 (pure air at E₀) | air 1 |
//! | `air_below_hu` (−200) | water 1 + HU/1000 (= 0.8) |
//! | `bone_above_hu` (200) | water 1 + HU/1000 (= 1.2) |
//! | 1559.1 (cortical bone at E₀) | cortical_bone 1 |
//! | above | cortical_bone (1000 + HU)/(1000 + 1559.1) (denser bone) |
//!
//! So below −200 HU air blends into water (lung: air–tissue mixture), between −200 and 200 HU
//! tissue is water at density `1 + HU/1000` g/cm³, above 200 HU it blends into cortical bone.
//! With `iodine_contrast` the soft range ends at `iodine_window_hu[0]` (100): from there to
//! `iodine_window_hu[1]` (400) the density stays at `1 + 100/1000` and the excess HU is carried
//! by iodine, `f_iodine = (HU − 100)·μ_water/(1000·μ_iodine)` at E₀ (≈ 26 HU per mg/mL, the
//! usual rule of thumb at 120 kVp); bone blending starts at the window's top.

use super::spectral::MaterialVolumes;
use crate::geometry::VolumeGrid;
use crate::physics::Material;
use crate::{Error, Result};
use ndarray::Array3;
use ndarray_npy::{ReadNpyError, ReadNpyExt};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Calibration energy of the HU → material mapping, keV.
pub const CALIBRATION_KEV: f64 = 70.0;
/// Linear attenuation at 70 keV, cm⁻¹, from `shared/data/nist/mu_over_rho.csv` (xraydb/Elam
/// μ/ρ × NIST density): water, dry air, ICRU-44 cortical bone, iodine.
const MU70_WATER: f64 = 0.192853;
const MU70_AIR: f64 = 0.000210843;
const MU70_CORTICAL_BONE: f64 = 0.493531;
const MU70_IODINE: f64 = 24.7269;

/// HU of a material at nominal density at the calibration energy.
fn hu_at_calibration(mu: f64) -> f64 {
    1000.0 * (mu / MU70_WATER - 1.0)
}

/// HU → material fractions; see the module docs for the knot table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HuMapping {
    /// Below this HU air blends in (air fraction 1 at −998.9 HU, 0 here).
    pub air_below_hu: f64,
    /// Above this HU cortical bone blends in (pure bone at 1559.1 HU).
    pub bone_above_hu: f64,
    /// Give contrast-enhanced soft tissue in `iodine_window_hu` an iodine fraction.
    pub iodine_contrast: bool,
    /// [low, high] HU of the iodine window (used when `iodine_contrast`).
    pub iodine_window_hu: [f64; 2],
}

impl Default for HuMapping {
    fn default() -> Self {
        HuMapping {
            air_below_hu: -200.0,
            bone_above_hu: 200.0,
            iodine_contrast: false,
            iodine_window_hu: [100.0, 400.0],
        }
    }
}

/// Materials a composition can hold, in [`Material::ALL`] order.
const KNOT_MATERIALS: [Material; 4] = [
    Material::Water,
    Material::Air,
    Material::CorticalBone,
    Material::Iodine,
];

impl HuMapping {
    /// HU of pure air and pure cortical bone at the calibration energy.
    pub fn air_hu() -> f64 {
        hu_at_calibration(MU70_AIR)
    }

    /// HU of cortical bone at nominal density at the calibration energy.
    pub fn bone_hu() -> f64 {
        hu_at_calibration(MU70_CORTICAL_BONE)
    }

    /// Check that the knots increase strictly: air < `air_below_hu` < `bone_above_hu` (or the
    /// iodine window) < bone.
    pub fn validate(&self) -> Result<()> {
        let mut names = vec!["air_below_hu"];
        let mut values = vec![self.air_below_hu];
        if self.iodine_contrast {
            names.extend(["iodine_window_hu[0]", "iodine_window_hu[1]"]);
            values.extend(self.iodine_window_hu);
        } else {
            names.push("bone_above_hu");
            values.push(self.bone_above_hu);
        }
        let mut prev = ("the HU of air", Self::air_hu());
        for (name, v) in names.into_iter().zip(values) {
            if !(v.is_finite() && v > prev.1) {
                return Err(Error::invalid(
                    name,
                    format!(
                        "must be finite and above {} ({:.1}), got {v}",
                        prev.0, prev.1
                    ),
                ));
            }
            prev = (name, v);
        }
        if prev.1 >= Self::bone_hu() {
            return Err(Error::invalid(
                prev.0,
                format!(
                    "must be below the HU of cortical bone ({:.1}), got {}",
                    Self::bone_hu(),
                    prev.1
                ),
            ));
        }
        Ok(())
    }

    /// The knots (HU, fractions in `KNOT_MATERIALS` order), increasing in HU.
    fn knots(&self) -> Vec<(f64, [f64; 4])> {
        let water = |h: f64| [1.0 + h / 1000.0, 0.0, 0.0, 0.0];
        let mut k = vec![
            (Self::air_hu(), [0.0, 1.0, 0.0, 0.0]),
            (self.air_below_hu, water(self.air_below_hu)),
        ];
        if self.iodine_contrast {
            let [lo, hi] = self.iodine_window_hu;
            let iodine = (hi - lo) * MU70_WATER / (1000.0 * MU70_IODINE);
            k.push((lo, water(lo)));
            k.push((hi, [1.0 + lo / 1000.0, 0.0, 0.0, iodine]));
        } else {
            k.push((self.bone_above_hu, water(self.bone_above_hu)));
        }
        k.push((Self::bone_hu(), [0.0, 0.0, 1.0, 0.0]));
        k
    }

    /// Fractions at `hu`, in `KNOT_MATERIALS` order, given the knots.
    fn composition_from(knots: &[(f64, [f64; 4])], hu: f64) -> [f64; 4] {
        let (first, last) = (knots[0], knots[knots.len() - 1]);
        if hu.is_nan() || hu <= first.0 {
            return first.1;
        }
        if hu >= last.0 {
            // Denser bone: scale the density so that the HU is kept.
            let scale = (1000.0 + hu) / (1000.0 + last.0);
            return last.1.map(|f| f * scale);
        }
        let i = knots
            .partition_point(|k| k.0 <= hu)
            .clamp(1, knots.len() - 1);
        let ((h0, a), (h1, b)) = (knots[i - 1], knots[i]);
        let s = (hu - h0) / (h1 - h0);
        [0, 1, 2, 3].map(|m| a[m] + s * (b[m] - a[m]))
    }

    /// The materials this mapping produces, in [`Material::ALL`] order.
    pub fn materials(&self) -> Vec<Material> {
        let n = if self.iodine_contrast { 4 } else { 3 };
        KNOT_MATERIALS[..n].to_vec()
    }

    /// Fractions at one HU value, one per entry of [`Self::materials`].
    pub fn composition(&self, hu: f64) -> Vec<(Material, f64)> {
        let f = Self::composition_from(&self.knots(), hu);
        self.materials().into_iter().zip(f).collect()
    }

    /// Fraction volumes of an HU volume, one per entry of [`Self::materials`].
    pub fn fractions(&self, hu: &Array3<f32>) -> Result<MaterialVolumes> {
        self.validate()?;
        let knots = self.knots();
        // Logical (z, y, x) order, whatever the memory layout.
        let values: Vec<f32> = hu.iter().copied().collect();
        let comps: Vec<[f64; 4]> = values
            .par_iter()
            .map(|&h| Self::composition_from(&knots, h as f64))
            .collect();
        self.materials()
            .into_iter()
            .enumerate()
            .map(|(k, m)| {
                let values: Vec<f32> = comps.iter().map(|c| c[k] as f32).collect();
                Array3::from_shape_vec(hu.raw_dim(), values)
                    .map(|a| (m, a))
                    .map_err(|e| Error::invalid("hu", e.to_string()))
            })
            .collect()
    }
}

/// A CT volume in HU, stored `[z][y][x]`, centred on the isocentre.
#[derive(Clone, Debug, PartialEq)]
pub struct HuVolume {
    pub hu: Array3<f32>,
    /// Voxel size (dz, dy, dx), mm.
    pub voxel_zyx: [f64; 3],
}

impl HuVolume {
    /// A volume from its array and voxel size (dz, dy, dx) in mm.
    pub fn new(hu: Array3<f32>, voxel_zyx: [f64; 3]) -> Result<Self> {
        for (k, d) in voxel_zyx.iter().enumerate() {
            crate::error::ensure_positive(format!("voxel_zyx[{k}]"), *d)?;
        }
        if hu.is_empty() {
            return Err(Error::invalid(
                "shape",
                format!("the volume is empty: {:?}", hu.shape()),
            ));
        }
        Ok(HuVolume { hu, voxel_zyx })
    }

    /// Load an int16 `.npy` stored `(z, y, x)`. Errors name the file, and say which dtype or
    /// dimensionality was found when it is not int16 / 3-D.
    pub fn load(path: impl AsRef<Path>, voxel_zyx: [f64; 3]) -> Result<Self> {
        let path = path.as_ref();
        let file = crate::scene::npy::open_checked(path).map_err(|e| Error::io(path, e))?;
        let hu = Array3::<i16>::read_npy(file).map_err(|e| match e {
            ReadNpyError::WrongDescriptor(d) => Error::field(
                path,
                "dtype",
                format!("expected int16 ('<i2') Hounsfield units, found dtype {d}"),
            ),
            ReadNpyError::WrongNdim(_, n) => Error::field(
                path,
                "shape",
                format!("expected a 3-D (z, y, x) array, found a {n}-D array"),
            ),
            ReadNpyError::Io(io) => Error::io(path, io),
            other => Error::field(path, "data", other.to_string()),
        })?;
        HuVolume::new(hu.mapv(f32::from), voxel_zyx).map_err(|e| e.in_file(path))
    }

    /// The grid of the volume's own voxels, centred on the isocentre.
    pub fn grid(&self) -> VolumeGrid {
        let (nz, ny, nx) = self.hu.dim();
        let [dz, dy, dx] = self.voxel_zyx;
        VolumeGrid {
            nx,
            ny,
            nz,
            dx,
            dy,
            dz,
            offset: [0.0; 3],
        }
    }

    /// A cubic grid of `n³` isotropic voxels, centred on the isocentre, that covers the volume
    /// (voxel size = largest extent / n).
    pub fn cube_grid(&self, n: usize) -> Result<VolumeGrid> {
        if n == 0 {
            return Err(Error::invalid("n", "must be at least 1"));
        }
        let s = self.grid().size();
        Ok(VolumeGrid::cube(n, s[0].max(s[1]).max(s[2]) / n as f64))
    }

    /// Resample along z (linear interpolation) to slices of thickness `min(dy, dx)`, keeping the
    /// z extent up to rounding to whole slices; the slab stays centred.
    pub fn isotropic_z(&self) -> HuVolume {
        let (nz, ny, nx) = self.hu.dim();
        let [dz, dy, dx] = self.voxel_zyx;
        let new_dz = dy.min(dx);
        let new_nz = ((nz as f64 * dz / new_dz).round() as usize).max(1);
        let plane = ny * nx;
        let src = self.hu.as_standard_layout();
        let src = src.as_slice().unwrap_or(&[]);
        let mut out = vec![0.0f32; new_nz * plane];
        out.par_chunks_mut(plane).enumerate().for_each(|(i, slab)| {
            let z = (i as f64 + 0.5 - new_nz as f64 / 2.0) * new_dz;
            let k = (z / dz + nz as f64 / 2.0 - 0.5).clamp(0.0, (nz - 1) as f64);
            let k0 = (k.floor() as usize).min(nz - 1);
            let k1 = (k0 + 1).min(nz - 1);
            let w = (k - k0 as f64) as f32;
            let (a, b) = (&src[k0 * plane..][..plane], &src[k1 * plane..][..plane]);
            for ((o, &x), &y) in slab.iter_mut().zip(a).zip(b) {
                *o = x + w * (y - x);
            }
        });
        HuVolume {
            hu: Array3::from_shape_vec((new_nz, ny, nx), out)
                .unwrap_or_else(|_| Array3::zeros((new_nz, ny, nx))),
            voxel_zyx: [new_dz, dy, dx],
        }
    }

    /// Trilinear resampling onto `grid`: points outside the volume's outer faces are air
    /// (−1000 HU); within half a voxel of a face the edge voxel is extended.
    pub fn resample(&self, grid: &VolumeGrid) -> Result<Array3<f32>> {
        grid.validate().map_err(|e| e.under("grid"))?;
        let own = self.grid();
        let (nz, ny, nx) = self.hu.dim();
        let src = self.hu.as_standard_layout();
        let src = src.as_slice().unwrap_or(&[]);
        let n = [nx, ny, nz];
        let mut out = vec![0.0f32; grid.len()];
        out.par_chunks_mut(grid.nx)
            .enumerate()
            .for_each(|(zy, line)| {
                let (iz, iy) = (zy / grid.ny, zy % grid.ny);
                for (ix, o) in line.iter_mut().enumerate() {
                    let q = own.world_to_index(grid.voxel_centre(ix, iy, iz));
                    if (0..3).any(|k| !(q[k] >= -0.5 && q[k] <= n[k] as f64 - 0.5)) {
                        *o = AIR_HU;
                        continue;
                    }
                    let mut i0 = [0usize; 3];
                    let mut w = [0.0f64; 3];
                    for k in 0..3 {
                        let c = q[k].clamp(0.0, (n[k] - 1) as f64);
                        i0[k] = (c.floor() as usize).min(n[k] - 1);
                        w[k] = c - i0[k] as f64;
                    }
                    let mut v = 0.0f64;
                    for corner in 0..8 {
                        let mut weight = 1.0;
                        let mut idx = [0usize; 3];
                        for k in 0..3 {
                            let up = corner >> k & 1 == 1;
                            weight *= if up { w[k] } else { 1.0 - w[k] };
                            idx[k] = if up { (i0[k] + 1).min(n[k] - 1) } else { i0[k] };
                        }
                        if weight > 0.0 {
                            v += weight * src[(idx[2] * ny + idx[1]) * nx + idx[0]] as f64;
                        }
                    }
                    *o = v as f32;
                }
            });
        Array3::from_shape_vec(grid.shape_zyx(), out)
            .map_err(|e| Error::invalid("grid", e.to_string()))
    }
}

/// HU assigned outside the CT volume (air).
pub const AIR_HU: f32 = -1000.0;

/// Load `path` (int16 `(z, y, x)` HU, voxel size `(dz, dy, dx)` mm), make it isotropic along z,
/// resample onto `grid` and map HU to material fractions.
pub fn hu_material_volumes(
    path: impl AsRef<Path>,
    voxel_zyx: [f64; 3],
    grid: &VolumeGrid,
    mapping: &HuMapping,
) -> Result<MaterialVolumes> {
    let path = path.as_ref();
    mapping.validate().map_err(|e| e.under("hu_mapping"))?;
    let hu = HuVolume::load(path, voxel_zyx)?
        .isotropic_z()
        .resample(grid)?;
    mapping.fractions(&hu)
}

#[cfg(test)]
mod tests;
