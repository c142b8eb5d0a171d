//! The normalised world the Gaussians live in (R²-Gaussian's convention, extended to densities).
//!
//! Lengths are multiplied by `scale = 2 / (largest volume edge in mm)`, so the volume spans
//! at most `[-1, 1]` per axis around its (scaled) offset; every learning rate, scale bound and
//! threshold of the trainer is in these units. Densities are divided by `density_scale` (mm⁻¹),
//! chosen from the FDK initialisation so that the object's densities are O(1). A line integral
//! `p` (dimensionless) becomes `p · scale / density_scale` in the normalised world, and a
//! normalised density `ρ` is `ρ · density_scale` mm⁻¹.

use crate::{Error, Result};
use prism_domain::geometry::{Geometry, ViewVectors, VolumeGrid};
use prism_render::VoxelGrid;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct World {
    /// Normalised length units per mm.
    pub scale: f64,
    /// mm⁻¹ per normalised density unit.
    pub density_scale: f64,
}

impl World {
    /// The world of `geometry`'s volume with densities in units of `density_scale` mm⁻¹.
    pub fn new(geometry: &Geometry, density_scale: f64) -> Result<Self> {
        let size = geometry.volume.size();
        let edge = size[0].max(size[1]).max(size[2]);
        if !(edge.is_finite() && edge > 0.0) {
            return Err(Error::invalid("geometry.volume", "has no extent"));
        }
        let world = World {
            scale: 2.0 / edge,
            density_scale,
        };
        world.validate()?;
        Ok(world)
    }

    /// Both scales finite and positive (a stored world is checked on load: a negative
    /// `density_scale` would turn every μ negative).
    pub fn validate(&self) -> Result<()> {
        for (field, v) in [
            ("world_scale", self.scale),
            ("density_scale", self.density_scale),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::invalid(
                    field,
                    format!("must be finite and > 0, got {v}"),
                ));
            }
        }
        Ok(())
    }

    /// `geometry` with every length multiplied by [`World::scale`].
    pub fn geometry(&self, g: &Geometry) -> Geometry {
        let s = self.scale;
        let mut out = g.clone();
        out.dso *= s;
        out.dsd *= s;
        out.detector.pitch_u *= s;
        out.detector.pitch_v *= s;
        out.detector.offset_u *= s;
        out.detector.offset_v *= s;
        out.volume = self.volume(&g.volume);
        // Positions and pixel steps scale; a parallel beam's ray direction may (any length).
        if let Some(w) = &mut out.vectors {
            for v in w.iter_mut() {
                *v = ViewVectors::from(<[f64; 12]>::from(*v).map(|x| x * s));
            }
        }
        out
    }

    /// A volume grid in normalised units.
    pub fn volume(&self, v: &VolumeGrid) -> VolumeGrid {
        let s = self.scale;
        VolumeGrid {
            dx: v.dx * s,
            dy: v.dy * s,
            dz: v.dz * s,
            offset: v.offset.map(|o| o * s),
            ..v.clone()
        }
    }

    /// The render op's grid for a (millimetre) volume grid.
    pub fn voxel_grid(&self, v: &VolumeGrid) -> VoxelGrid {
        let n = self.volume(v);
        VoxelGrid {
            dims: [n.nx, n.ny, n.nz],
            voxel: [n.dx, n.dy, n.dz],
            offset: n.offset,
        }
    }

    /// Factor from a measured line integral to the normalised world's.
    pub fn projection_factor(&self) -> f64 {
        self.scale / self.density_scale
    }
}
