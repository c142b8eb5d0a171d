//! Queries of a trained spectral Gaussian model: any coordinate τ* of the spectral axis by
//! piecewise-linear interpolation of the per-channel raw densities between the neighbouring
//! observed grid points (paper eq. `target_transform_interpolation`; interpolating u⁽ᶜ⁾ + Δu is
//! interpolating Δu, since u⁽ᶜ⁾ does not depend on τ), then voxelize or render. No optimisation.
//! Outside the observed grid the query is refused unless extrapolation is asked for.

pub mod answer;
pub mod basis;
pub mod holdout;

pub use answer::{Answer, Ask, SpectralModel};
pub use basis::{BASIS_FILE, BasisModel};
pub use holdout::{Holdout, HoldoutScore, Predictor, predict_holdout};

use crate::gaussians::io::{LoadedModel, ModelInfo, load_model};
use crate::gaussians::volume::{render_views, volumes_with};
use crate::{Error, Result};
use burn::tensor::{Device, Tensor};
use ndarray::{Array3, Axis};
use prism_gscnet::{Extrapolation, SpectralGrid, interpolate_curve};
use std::path::Path;

/// Raw densities `[K, 1]` at τ* from the per-channel raw columns `raw` `[K, M]`.
pub fn raw_at(
    raw: &Tensor<2>,
    info: &ModelInfo,
    tau: f64,
    extrapolation: Extrapolation,
) -> Result<Tensor<2>> {
    if !tau.is_finite() {
        return Err(Error::invalid(
            "tau",
            format!("τ* must be a finite number (got {tau})"),
        ));
    }
    let [k, m] = raw.dims();
    if m == 1 {
        let t0 = info.tau.first().copied().unwrap_or(0.0);
        if (tau - t0).abs() > 1e-9 && extrapolation == Extrapolation::Refuse {
            return Err(Error::invalid(
                "tau",
                format!(
                    "the model has one channel (τ = {t0}); τ* = {tau} would be an extrapolation"
                ),
            ));
        }
        return Ok(raw.clone());
    }
    let grid = SpectralGrid::new(info.tau.iter().map(|&t| t as f32).collect())?;
    let v = interpolate_curve(raw.clone(), &grid, tau as f32, extrapolation).map_err(|e| {
        Error::invalid(
            "tau",
            format!(
                "{e} (observed τ: {:?}; pass --extrapolate to allow it)",
                info.tau
            ),
        )
    })?;
    Ok(v.reshape([k, 1]))
}

/// Where on the spectral axis a query is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum QueryAt {
    /// A physical coordinate in the model's unit (keV, kVp, λ, …).
    Coordinate(f64),
    /// Normalised τ.
    Tau(f64),
}

/// A loaded spectral model answering queries.
pub struct Query {
    pub loaded: LoadedModel,
    raw: Tensor<2>,
}

impl Query {
    /// Open a spectral model file (a run directory's is `RunDir::spectral_model`).
    pub fn open(path: &Path, device: &Device) -> Result<Self> {
        let loaded = load_model(path, device)?;
        let raw = loaded.model.densities.value.clone();
        Ok(Query { loaded, raw })
    }

    /// τ of a query.
    pub fn tau(&self, at: QueryAt) -> f64 {
        match at {
            QueryAt::Tau(t) => t,
            QueryAt::Coordinate(v) => self.loaded.info.tau_of(v),
        }
    }

    fn raw(&self, at: QueryAt, extrapolate: bool) -> Result<Tensor<2>> {
        let mode = if extrapolate {
            Extrapolation::Linear
        } else {
            Extrapolation::Refuse
        };
        raw_at(&self.raw, &self.loaded.info, self.tau(at), mode)
    }

    /// The attenuation volume (mm⁻¹, `[z][y][x]`) on the run's grid.
    pub fn volume(&self, at: QueryAt, extrapolate: bool) -> Result<Array3<f32>> {
        let l = &self.loaded;
        let raw = self.raw(at, extrapolate)?;
        Ok(
            volumes_with(&l.model, raw, &l.info.geometry.volume, &l.world)?
                .index_axis(Axis(0), 0)
                .to_owned(),
        )
    }

    /// Line integrals `[view][row][col]` at every view of the run's geometry.
    pub fn projections(&self, at: QueryAt, extrapolate: bool) -> Result<Array3<f32>> {
        let l = &self.loaded;
        let raw = self.raw(at, extrapolate)?;
        let views: Vec<usize> = (0..l.info.geometry.views()).collect();
        render_views(
            &l.model,
            raw,
            &l.world,
            &l.info.geometry,
            &views,
            &l.info.projection.options(),
        )
    }
}
