//! Plain-number settings of the render ops (passed to the Burn ops as ordinary arguments).

use crate::error::{RenderError, Result};

/// How each pixel's line integral of a Gaussian is computed (YAML/JSON `affine` | `exact`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProjectionMode {
    /// Local-affine (EWA) splatting: one 2D Gaussian per view with the exact central-ray integral
    /// `μ = √(2π / r̂ᵀΣ⁻¹r̂)` as its weight. Exact for parallel beam; for cone beam the lateral
    /// profile drifts with the Gaussian's angular size. Integrates over the whole ray line.
    #[default]
    Affine,
    /// Closed-form integral of the 3D Gaussian along each pixel's ray segment (source or start
    /// plane to detector): `√(2π/a)·e^{−q/2}·½[erf(u₁) − erf(u₀)]`, evaluated per pixel in f64
    /// on the CPU backends and in f32 on wgpu (offsets taken from the Gaussian's centre, so
    /// nothing subtracts two large coordinates).
    Exact,
}

impl ProjectionMode {
    /// The name configs use (`affine`, `exact`).
    pub fn name(self) -> &'static str {
        match self {
            ProjectionMode::Affine => "affine",
            ProjectionMode::Exact => "exact",
        }
    }
}

/// Settings of [`crate::project`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProjectOptions {
    pub mode: ProjectionMode,
    /// Cut-off radius in Mahalanobis units: a pixel receives a Gaussian only if its ray passes
    /// within `cutoff` standard deviations of the centre (affine: of the 2D footprint). Upstream
    /// R²-Gaussian uses 3; the dropped tail is `e^{−cutoff²/2}` of the peak (1.1 % at 3).
    pub cutoff: f64,
    /// Cone beam, affine mode: Gaussians whose centre depth is `≤ near_fraction · sdd` are culled
    /// (the affine Jacobian diverges at the source). The exact mode needs no near plane.
    pub near_fraction: f64,
}

impl Default for ProjectOptions {
    fn default() -> Self {
        Self {
            mode: ProjectionMode::Affine,
            cutoff: 3.0,
            near_fraction: 1e-3,
        }
    }
}

impl ProjectOptions {
    pub fn exact() -> Self {
        Self {
            mode: ProjectionMode::Exact,
            ..Self::default()
        }
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.cutoff.is_finite() && self.cutoff > 0.0) {
            return Err(RenderError::invalid(
                "cutoff",
                format!("must be finite and > 0, got {}", self.cutoff),
            ));
        }
        if !(self.near_fraction.is_finite()
            && self.near_fraction >= 0.0
            && self.near_fraction < 1.0)
        {
            return Err(RenderError::invalid(
                "near_fraction",
                format!("must be in [0, 1), got {}", self.near_fraction),
            ));
        }
        Ok(())
    }
}

/// A regular voxel grid in world coordinates, matching Prism's `VolumeGrid`: voxel `(ix, iy, iz)`
/// has its centre at `offset + (i + ½ − n/2)·voxel` per axis; volumes are stored `[z][y][x]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoxelGrid {
    /// Voxel counts `[nx, ny, nz]`.
    pub dims: [usize; 3],
    /// Voxel size `[dx, dy, dz]` (length units).
    pub voxel: [f64; 3],
    /// Grid centre `[x, y, z]` (length units).
    pub offset: [f64; 3],
}

impl VoxelGrid {
    /// Centre of voxel index `i` along `axis`.
    #[inline]
    pub fn centre(&self, axis: usize, i: usize) -> f64 {
        self.offset[axis] + (i as f64 + 0.5 - self.dims[axis] as f64 / 2.0) * self.voxel[axis]
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn validate(&self) -> Result<()> {
        for (a, name) in ["x", "y", "z"].iter().enumerate() {
            if self.dims[a] == 0 || self.dims[a] > (1 << 20) {
                return Err(RenderError::invalid(
                    format!("grid.dims.{name}"),
                    format!("must be in 1..=2^20, got {}", self.dims[a]),
                ));
            }
            if !(self.voxel[a].is_finite() && self.voxel[a] > 0.0) {
                return Err(RenderError::invalid(
                    format!("grid.voxel.{name}"),
                    format!("must be finite and > 0, got {}", self.voxel[a]),
                ));
            }
            if !self.offset[a].is_finite() {
                return Err(RenderError::invalid(
                    format!("grid.offset.{name}"),
                    "must be finite",
                ));
            }
        }
        Ok(())
    }
}

/// Settings of [`crate::voxelize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoxelizeOptions {
    /// Cut-off radius in Mahalanobis units (a voxel receives a Gaussian only within it).
    pub cutoff: f64,
}

impl Default for VoxelizeOptions {
    fn default() -> Self {
        Self { cutoff: 3.0 }
    }
}

impl VoxelizeOptions {
    pub fn validate(&self) -> Result<()> {
        if !(self.cutoff.is_finite() && self.cutoff > 0.0) {
            return Err(RenderError::invalid(
                "cutoff",
                format!("must be finite and > 0, got {}", self.cutoff),
            ));
        }
        Ok(())
    }
}
