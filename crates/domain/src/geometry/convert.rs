//! Conversions from other tools' geometry descriptions into a Prism [`Geometry`].
//!
//! * [`R2Scanner`]: the `scanner` block of an R²-Gaussian / NAF `meta_data.json`. Its camera
//!   convention is Prism's (source at `DSO·(cos θ, sin θ, 0)`, row 0 at the top), so projections
//!   load without flips; its volumes are stored `[x][y][z]` and must be transposed to `[z][y][x]`.
//!   R²-Gaussian ignores `offDetector` in its rasterizer and treats a parallel detector as spanning
//!   [−1, 1]²; Prism honours both the offset and the real detector size.
//! * [`TigreGeometry`]: TIGRE's Python geometry fields (`(z, y, x)` and `(v, u)` orders). TIGRE's
//!   projection row 0 is the *lowest* z and its v offset points up, so rows must be flipped
//!   (`proj[:, ::-1, :]`) and `offset_v = −offDetector[0]`.

use super::{Beam, Detector, Geometry, VolumeGrid};
use crate::{Error, Result};
use serde::Deserialize;

/// The `scanner` block of an R²-Gaussian `meta_data.json` (lengths in the file's unit).
#[derive(Clone, Debug, Deserialize)]
#[allow(non_snake_case)]
pub struct R2Scanner {
    #[serde(default = "default_mode")]
    pub mode: String,
    pub DSD: f64,
    pub DSO: f64,
    /// `[rows (v), cols (u)]`.
    pub nDetector: [usize; 2],
    /// Full detector size `[v, u]`.
    pub sDetector: [f64; 2],
    /// Voxel counts `[x, y, z]`.
    pub nVoxel: [usize; 3],
    /// Full volume size `[x, y, z]`.
    pub sVoxel: [f64; 3],
    /// Volume centre `[x, y, z]`.
    #[serde(default)]
    pub offOrigin: [f64; 3],
    /// Detector offset `[u, v]`.
    #[serde(default)]
    pub offDetector: [f64; 2],
}

fn default_mode() -> String {
    "cone".into()
}

/// `cone` or `parallel`, as both tools spell it.
fn beam_mode(field: &str, mode: &str) -> Result<Beam> {
    match mode {
        "cone" => Ok(Beam::Cone),
        "parallel" => Ok(Beam::Parallel),
        other => Err(Error::invalid(
            field,
            format!("unknown beam mode `{other}` (expected `cone` or `parallel`)"),
        )),
    }
}

impl R2Scanner {
    /// The Prism geometry for these scanner fields and the given view angles (radians).
    pub fn to_geometry(&self, angles_rad: Vec<f64>) -> Result<Geometry> {
        let beam = beam_mode("scanner.mode", &self.mode)?;
        let [rows, cols] = self.nDetector;
        let [nx, ny, nz] = self.nVoxel;
        let nonzero = |field: &str, n: usize| {
            if n == 0 {
                Err(Error::invalid(field, "must be at least 1"))
            } else {
                Ok(n as f64)
            }
        };
        let g = Geometry {
            beam,
            dso: self.DSO,
            dsd: self.DSD,
            detector: Detector {
                rows,
                cols,
                pitch_u: self.sDetector[1] / nonzero("scanner.nDetector[1]", cols)?,
                pitch_v: self.sDetector[0] / nonzero("scanner.nDetector[0]", rows)?,
                offset_u: self.offDetector[0],
                offset_v: self.offDetector[1],
            },
            volume: VolumeGrid {
                nx,
                ny,
                nz,
                dx: self.sVoxel[0] / nonzero("scanner.nVoxel[0]", nx)?,
                dy: self.sVoxel[1] / nonzero("scanner.nVoxel[1]", ny)?,
                dz: self.sVoxel[2] / nonzero("scanner.nVoxel[2]", nz)?,
                offset: self.offOrigin,
            },
            angles_rad,
            vectors: None,
        };
        g.validate().map_err(|e| e.under("scanner"))?;
        Ok(g)
    }
}

/// TIGRE's Python geometry fields, in TIGRE's own orders.
#[derive(Clone, Debug, Deserialize)]
#[allow(non_snake_case)]
pub struct TigreGeometry {
    #[serde(default = "default_mode")]
    pub mode: String,
    pub DSD: f64,
    pub DSO: f64,
    /// `(v, u)`.
    pub nDetector: [usize; 2],
    /// `(v, u)`.
    pub dDetector: [f64; 2],
    /// `(v, u)`, v pointing up (+z).
    #[serde(default)]
    pub offDetector: [f64; 2],
    /// `(z, y, x)`.
    pub nVoxel: [usize; 3],
    /// `(z, y, x)`.
    pub dVoxel: [f64; 3],
    /// `(z, y, x)`.
    #[serde(default)]
    pub offOrigin: [f64; 3],
}

impl TigreGeometry {
    /// The Prism geometry for these TIGRE fields and angles (radians). Projections recorded by
    /// TIGRE must additionally have their rows flipped.
    pub fn to_geometry(&self, angles_rad: Vec<f64>) -> Result<Geometry> {
        let beam = beam_mode("mode", &self.mode)?;
        let g = Geometry {
            beam,
            dso: self.DSO,
            dsd: self.DSD,
            detector: Detector {
                rows: self.nDetector[0],
                cols: self.nDetector[1],
                pitch_u: self.dDetector[1],
                pitch_v: self.dDetector[0],
                offset_u: self.offDetector[1],
                offset_v: -self.offDetector[0],
            },
            volume: VolumeGrid {
                nx: self.nVoxel[2],
                ny: self.nVoxel[1],
                nz: self.nVoxel[0],
                dx: self.dVoxel[2],
                dy: self.dVoxel[1],
                dz: self.dVoxel[0],
                offset: [self.offOrigin[2], self.offOrigin[1], self.offOrigin[0]],
            },
            angles_rad,
            vectors: None,
        };
        g.validate()?;
        Ok(g)
    }
}
