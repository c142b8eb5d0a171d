//! Gaussian parameters on the host: what initialisation, densification, save/load and export
//! read and write. Raw (pre-activation) values, normalised world (see [`super::World`]).

use crate::{Error, Result};

/// Bounds of the scale activation `s = min + (max − min)·sigmoid(raw)`, normalised length units.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScaleBounds {
    pub min: f64,
    pub max: f64,
}

impl ScaleBounds {
    pub fn validate(&self) -> Result<()> {
        if !(self.min.is_finite() && self.min > 0.0 && self.max.is_finite() && self.max > self.min)
        {
            return Err(Error::invalid(
                "scale_bounds",
                format!("need 0 < min < max, got min {} max {}", self.min, self.max),
            ));
        }
        Ok(())
    }

    /// Activated scale of a raw value.
    pub fn activate(&self, raw: f64) -> f64 {
        self.min + (self.max - self.min) * sigmoid(raw)
    }

    /// The raw value of scale `s`, clamped 1e-6 (relative) inside the bounds so that no raw value
    /// is infinite (upstream R²-Gaussian's split children could reach −∞ and freeze).
    pub fn raw(&self, s: f64) -> f64 {
        let f = ((s - self.min) / (self.max - self.min)).clamp(1e-6, 1.0 - 1e-6);
        (f / (1.0 - f)).ln()
    }
}

pub(crate) fn sigmoid(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// `softplus(x) = ln(1 + eˣ)`, overflow-free.
pub fn softplus(x: f64) -> f64 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// Inverse of [`softplus`] for `y > 0`: `ln(eʸ − 1)`, stable for tiny and large `y`.
pub fn inverse_softplus(y: f64) -> f64 {
    let y = y.max(1e-30);
    if y > 30.0 { y } else { y.exp_m1().ln() }
}

/// K Gaussians with M density channels, raw parameters, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct HostGaussians {
    /// Channels per Gaussian (density columns).
    pub channels: usize,
    /// Centres `[K][3]`, normalised world.
    pub means: Vec<f32>,
    /// Raw scales `[K][3]` (see [`ScaleBounds`]).
    pub scales: Vec<f32>,
    /// Quaternions `[K][4]` (`w, x, y, z`, not necessarily unit: the render op normalises).
    pub rotations: Vec<f32>,
    /// Raw densities `[K][M]` (density = softplus(raw)).
    pub densities: Vec<f32>,
}

impl HostGaussians {
    pub fn empty(channels: usize) -> Self {
        HostGaussians {
            channels,
            means: vec![],
            scales: vec![],
            rotations: vec![],
            densities: vec![],
        }
    }

    /// Number of Gaussians K.
    pub fn len(&self) -> usize {
        self.means.len() / 3
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// Check that every array has K rows and every value is finite.
    pub fn validate(&self) -> Result<()> {
        let k = self.len();
        if self.channels == 0 {
            return Err(Error::invalid("channels", "must be at least 1"));
        }
        for (name, v, w) in [
            ("means", &self.means, 3),
            ("scales", &self.scales, 3),
            ("rotations", &self.rotations, 4),
            ("densities", &self.densities, self.channels),
        ] {
            if v.len() != k * w {
                return Err(Error::invalid(
                    name,
                    format!("has {} values, expected {k} × {w}", v.len()),
                ));
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(Error::invalid(
                    format!("{name}[{}][{}]", i / w, i % w),
                    "is not finite",
                ));
            }
        }
        Ok(())
    }

    /// Append Gaussian `i` of `src` (all channels).
    pub fn push_from(&mut self, src: &HostGaussians, i: usize) {
        let m = src.channels;
        self.means.extend_from_slice(&src.means[3 * i..3 * i + 3]);
        self.scales.extend_from_slice(&src.scales[3 * i..3 * i + 3]);
        self.rotations
            .extend_from_slice(&src.rotations[4 * i..4 * i + 4]);
        self.densities
            .extend_from_slice(&src.densities[m * i..m * i + m]);
    }

    /// Keep only the listed Gaussians, in that order (indices may repeat).
    pub fn select(&self, rows: &[usize]) -> HostGaussians {
        let mut out = HostGaussians::empty(self.channels);
        for &i in rows {
            out.push_from(self, i);
        }
        out
    }
}
