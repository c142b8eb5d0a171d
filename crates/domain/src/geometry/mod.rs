//! Scan geometry: cone and parallel beam, the detector, the volume grid, view angles, and the
//! per-view [`Camera`] the render ops consume.
//!
//! The convention is documented once, in `docs/geometry.md`; in short:
//!
//! * world axes x, y, z in millimetres; the rotation axis is +z through the world origin
//!   (the isocentre);
//! * view angle θ (radians) turns source and detector together counter-clockwise about +z seen
//!   from +z; the source sits at `DSO·(cos θ, sin θ, 0)`;
//! * detector columns (u) run along `(−sin θ, cos θ, 0)`, rows (v) run along −z: row 0 is the top
//!   of the detector (highest z); projections are stored `[view][row][col]`;
//! * pixel centre (row r, col c) is at `u = (c + ½ − cols/2)·pitch_u + offset_u`,
//!   `v = (r + ½ − rows/2)·pitch_v + offset_v` on the detector plane;
//! * volumes are stored `[z][y][x]` (x fastest); voxel (ix, iy, iz) has its centre at
//!   `offset + ((ix + ½ − nx/2)·dx, (iy + ½ − ny/2)·dy, (iz + ½ − nz/2)·dz)`.

mod convert;
mod vectors;

pub use convert::{R2Scanner, TigreGeometry};
pub use prism_camera::{Camera, Projection, Ray};
pub use vectors::{PERPENDICULAR, ViewVectors};
pub(crate) use vectors::{cross, dot, rotate, sub, unit};

use crate::error::{ensure_finite as finite, ensure_positive as positive};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Beam shape, shared by all views of a scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Beam {
    Cone,
    Parallel,
}

impl Beam {
    /// The camera model of this beam's views.
    pub fn projection(self) -> Projection {
        match self {
            Beam::Cone => Projection::Cone,
            Beam::Parallel => Projection::Parallel,
        }
    }

    /// A camera's focal length `f` for a detector plane `sdd` from the camera origin with
    /// pixels `pitch` apart: pixels (cone, `sdd / pitch`) or pixels per mm (parallel, `1 / pitch`).
    pub fn focal(self, sdd: f64, pitch: f64) -> f64 {
        match self {
            Beam::Cone => sdd / pitch,
            Beam::Parallel => 1.0 / pitch,
        }
    }
}

/// Flat-panel detector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Detector {
    /// Number of pixel rows (v) and columns (u).
    pub rows: usize,
    pub cols: usize,
    /// Pixel pitch along u (between columns) and v (between rows), mm.
    pub pitch_u: f64,
    pub pitch_v: f64,
    /// Shift of the detector centre within its plane, along u and v (v points down), mm.
    #[serde(default)]
    pub offset_u: f64,
    #[serde(default)]
    pub offset_v: f64,
}

impl Detector {
    /// Physical size (width along u, height along v), mm.
    pub fn size(&self) -> [f64; 2] {
        [
            self.cols as f64 * self.pitch_u,
            self.rows as f64 * self.pitch_v,
        ]
    }
}

/// Regular voxel grid of the reconstructed volume, stored `[z][y][x]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeGrid {
    /// Voxel counts along x, y, z.
    pub nx: usize,
    pub ny: usize,
    pub nz: usize,
    /// Voxel sizes along x, y, z, mm.
    pub dx: f64,
    pub dy: f64,
    pub dz: f64,
    /// Centre of the grid relative to the isocentre, (x, y, z), mm.
    #[serde(default)]
    pub offset: [f64; 3],
}

impl VolumeGrid {
    /// A cubic grid of `n³` voxels of size `voxel` centred on the isocentre.
    pub fn cube(n: usize, voxel: f64) -> Self {
        VolumeGrid {
            nx: n,
            ny: n,
            nz: n,
            dx: voxel,
            dy: voxel,
            dz: voxel,
            offset: [0.0; 3],
        }
    }

    /// Array shape `[nz, ny, nx]` of a volume on this grid.
    pub fn shape_zyx(&self) -> [usize; 3] {
        [self.nz, self.ny, self.nx]
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.nx * self.ny * self.nz
    }

    /// True when the grid has no voxels (never the case for a validated grid).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Voxel sizes (dx, dy, dz).
    pub fn voxel_size(&self) -> [f64; 3] {
        [self.dx, self.dy, self.dz]
    }

    /// Physical size (x, y, z), mm.
    pub fn size(&self) -> [f64; 3] {
        [
            self.nx as f64 * self.dx,
            self.ny as f64 * self.dy,
            self.nz as f64 * self.dz,
        ]
    }

    /// World position of the centre of voxel (ix, iy, iz).
    pub fn voxel_centre(&self, ix: usize, iy: usize, iz: usize) -> [f64; 3] {
        [
            self.offset[0] + (ix as f64 + 0.5 - self.nx as f64 / 2.0) * self.dx,
            self.offset[1] + (iy as f64 + 0.5 - self.ny as f64 / 2.0) * self.dy,
            self.offset[2] + (iz as f64 + 0.5 - self.nz as f64 / 2.0) * self.dz,
        ]
    }

    /// Continuous voxel index (x, y, z) of a world point: voxel centres sit at integers.
    pub fn world_to_index(&self, p: [f64; 3]) -> [f64; 3] {
        [
            (p[0] - self.offset[0]) / self.dx + self.nx as f64 / 2.0 - 0.5,
            (p[1] - self.offset[1]) / self.dy + self.ny as f64 / 2.0 - 0.5,
            (p[2] - self.offset[2]) / self.dz + self.nz as f64 / 2.0 - 0.5,
        ]
    }

    /// Axis-aligned bounds of the grid (outer voxel faces): (min, max) corners.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let s = self.size();
        let lo = [
            self.offset[0] - s[0] / 2.0,
            self.offset[1] - s[1] / 2.0,
            self.offset[2] - s[2] / 2.0,
        ];
        (lo, [lo[0] + s[0], lo[1] + s[1], lo[2] + s[2]])
    }

    /// Flat index of voxel (ix, iy, iz) in a `[z][y][x]` array.
    pub fn flat_index(&self, ix: usize, iy: usize, iz: usize) -> usize {
        (iz * self.ny + iy) * self.nx + ix
    }

    /// Check counts and sizes.
    pub fn validate(&self) -> Result<()> {
        for (name, n) in [("nx", self.nx), ("ny", self.ny), ("nz", self.nz)] {
            if n == 0 {
                return Err(Error::invalid(name, "must be at least 1"));
            }
        }
        for (name, d) in [("dx", self.dx), ("dy", self.dy), ("dz", self.dz)] {
            positive(name, d)?;
        }
        for (k, o) in self.offset.iter().enumerate() {
            finite(format!("offset[{k}]"), *o)?;
        }
        crate::memory::elements("n", &[self.nz, self.ny, self.nx])?;
        Ok(())
    }
}

/// A complete scan geometry: beam, distances, detector, volume grid and view angles; with
/// `vectors`, every view's pose is given explicitly ([`ViewVectors`]) and the circular fields
/// are the nominal scan they describe ([`Geometry::from_vectors`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Geometry {
    pub beam: Beam,
    /// Source to rotation axis distance, mm. Parallel beam: distance from the axis to the plane
    /// where rays start (any value that puts that plane outside the volume).
    pub dso: f64,
    /// Source to detector distance, mm (detector plane at `dsd − dso` beyond the axis).
    pub dsd: f64,
    pub detector: Detector,
    pub volume: VolumeGrid,
    /// View angles θ, radians, one per view.
    pub angles_rad: Vec<f64>,
    /// Per-view source, detector centre and pixel axes (ASTRA's `*_vec` rows), one per view:
    /// when given, they place every view, and the fields above are nominal.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vectors: Option<Vec<ViewVectors>>,
}

impl Geometry {
    /// `n` views evenly spaced over `total` radians from `start`, endpoint excluded
    /// (`linspace(start, start + total, n + 1)[:-1]`, as R²-Gaussian and TIGRE scripts do).
    pub fn uniform_angles(n: usize, start: f64, total: f64) -> Vec<f64> {
        (0..n)
            .map(|i| start + total * i as f64 / n as f64)
            .collect()
    }

    /// `n` views over a full turn starting at 0.
    pub fn full_turn(n: usize) -> Vec<f64> {
        Self::uniform_angles(n, 0.0, 2.0 * PI)
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.angles_rad.len()
    }

    /// The same scan restricted to the listed views (in that order), e.g. a channel's training
    /// views; view `i` of the result is view `views[i]` of `self`.
    pub fn with_views(&self, views: &[usize]) -> Geometry {
        Geometry {
            angles_rad: views.iter().map(|&v| self.angles_rad[v]).collect(),
            vectors: self
                .vectors
                .as_ref()
                .map(|w| views.iter().map(|&v| w[v]).collect()),
            ..self.clone()
        }
    }

    /// Geometric magnification at the isocentre (`DSD / DSO` for cone, 1 for parallel).
    pub fn magnification(&self) -> f64 {
        match self.beam {
            Beam::Cone => self.dsd / self.dso,
            Beam::Parallel => 1.0,
        }
    }

    /// Source position of view `view` (cone), or the centre of the rays' start plane (parallel).
    pub fn source(&self, view: usize) -> [f64; 3] {
        if self.vectors.is_some() {
            return self.camera(view).to_world([0.0; 3]);
        }
        let th = self.angles_rad[view];
        [self.dso * th.cos(), self.dso * th.sin(), 0.0]
    }

    /// The camera of view `view`: from its vectors if the geometry has them, else the circular
    /// scan's at its angle.
    pub fn camera(&self, view: usize) -> Camera {
        match &self.vectors {
            Some(w) => {
                let d = &self.detector;
                w[view]
                    .camera(self.beam, d.rows, d.cols, self.dso)
                    .expect("vectors are checked with the geometry")
            }
            None => self.camera_at(self.angles_rad[view]),
        }
    }

    /// Whether every view lies on the circular orbit of the nominal fields (no `vectors`).
    pub fn is_circular(&self) -> bool {
        self.vectors.is_none()
    }

    /// All views' cameras.
    pub fn cameras(&self) -> Vec<Camera> {
        (0..self.views()).map(|v| self.camera(v)).collect()
    }

    /// The camera at an arbitrary angle θ (radians) on the nominal circular orbit.
    pub fn camera_at(&self, theta: f64) -> Camera {
        let (s, c) = theta.sin_cos();
        let d = &self.detector;
        // Rows: x_c (u), y_c (v, down = −z), z_c (from the source towards the axis).
        let rotation = [[-s, c, 0.0], [0.0, 0.0, -1.0], [-c, -s, 0.0]];
        // The source at DSO·(cos θ, sin θ, 0) maps to the camera origin.
        let translation = [0.0, 0.0, self.dso];
        Camera {
            projection: self.beam.projection(),
            rotation,
            translation,
            fx: self.beam.focal(self.dsd, d.pitch_u),
            fy: self.beam.focal(self.dsd, d.pitch_v),
            cx: (d.cols as f64 - 1.0) / 2.0 - d.offset_u / d.pitch_u,
            cy: (d.rows as f64 - 1.0) / 2.0 - d.offset_v / d.pitch_v,
            rows: d.rows,
            cols: d.cols,
            sdd: self.dsd,
        }
    }

    /// Check every field; errors name the field (`dso`, `detector.pitch_u`, `angles_rad[3]`…).
    pub fn validate(&self) -> Result<()> {
        positive("dso", self.dso)?;
        positive("dsd", self.dsd)?;
        if self.dsd <= self.dso {
            return Err(Error::invalid(
                "dsd",
                format!(
                    "source-detector distance ({}) must exceed source-origin distance dso ({})",
                    self.dsd, self.dso
                ),
            ));
        }
        let d = &self.detector;
        if d.rows == 0 {
            return Err(Error::invalid("detector.rows", "must be at least 1"));
        }
        if d.cols == 0 {
            return Err(Error::invalid("detector.cols", "must be at least 1"));
        }
        positive("detector.pitch_u", d.pitch_u)?;
        positive("detector.pitch_v", d.pitch_v)?;
        finite("detector.offset_u", d.offset_u)?;
        finite("detector.offset_v", d.offset_v)?;
        self.volume.validate().map_err(|e| e.under("volume"))?;
        if self.angles_rad.is_empty() {
            return Err(Error::invalid("angles_rad", "the view list is empty"));
        }
        for (i, a) in self.angles_rad.iter().enumerate() {
            finite(format!("angles_rad[{i}]"), *a)?;
        }
        crate::memory::elements("detector", &[self.angles_rad.len(), d.rows, d.cols])?;
        // The whole volume must lie between the source and the detector.
        let (lo, hi) = self.volume.bounds();
        let reach = lo
            .iter()
            .zip(&hi)
            .take(2)
            .map(|(a, b)| a.abs().max(b.abs()).powi(2))
            .sum::<f64>()
            .sqrt();
        if let Some(w) = &self.vectors {
            return self.validate_vectors(w);
        }
        if self.beam == Beam::Cone && reach >= self.dso {
            return Err(Error::invalid(
                "volume",
                format!(
                    "the volume reaches {reach:.3} mm from the rotation axis, at or beyond the \
                     source (dso = {})",
                    self.dso
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
