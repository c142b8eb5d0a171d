//! Queries of a trained spectral Gaussian model: any coordinate τ* of the spectral axis by
//! piecewise-linear interpolation of the per-channel raw densities between the neighbouring
//! observed grid points (paper eq. `target_transform_interpolation`; interpolating u⁽ᶜ⁾ + Δu is
//! interpolating Δu, since u⁽ᶜ⁾ does not depend on τ), then voxelize or render. No optimisation.
//! Outside the observed grid the query is refused unless extrapolation is asked for.

use super::io::{LoadedModel, ModelInfo, load_model};
use super::model::{GaussianModel, softplus};
use super::trainer::{render_error, score_volume, volumes_with};
use super::world::World;
use crate::geometry::Geometry;
use crate::metrics::{SsimParams, projection_metrics};
use crate::scene::Scene;
use crate::{Error, Result};
use burn::tensor::{Device, Tensor};
use ndarray::{Array3, Axis};
use prism_gscnet::{Extrapolation, SpectralGrid, interpolate_curve};
use prism_render::{ProjectOptions, project};
use serde::{Deserialize, Serialize};
use std::fs;
use std::path::Path;

/// Name of the holdout report in a run directory.
pub const HOLDOUT_FILE: &str = "holdout.json";
/// The model file of a spectral run (`4dsg`, `4dsg-stage1`).
pub const MODEL_FILE: &str = "gaussians.safetensors";

/// Raw densities `[K, 1]` at τ* from the per-channel raw columns `raw` `[K, M]`.
pub fn raw_at(
    raw: &Tensor<2>,
    info: &ModelInfo,
    tau: f64,
    extrapolation: Extrapolation,
) -> Result<Tensor<2>> {
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
    let grid = SpectralGrid::new(info.tau.iter().map(|&t| t as f32).collect())
        .map_err(|e| Error::invalid("tau", e.to_string()))?;
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

/// Render `views` of `geometry` for one density column `raw` `[K, 1]` with `options`: line
/// integrals `[view][row][col]`.
pub fn render_views(
    model: &GaussianModel,
    raw: Tensor<2>,
    world: &World,
    geometry: &Geometry,
    views: &[usize],
    options: &ProjectOptions,
) -> Result<Array3<f32>> {
    let g_world = world.geometry(geometry);
    let mut gaussians = model.activate(None).gaussians;
    gaussians.densities = softplus(raw);
    let (rows, cols) = (geometry.detector.rows, geometry.detector.cols);
    let mut out = Array3::<f32>::zeros((views.len(), rows, cols));
    let f = (1.0 / world.projection_factor()) as f32;
    // A few views per call keeps the [V, 1, rows, cols] buffers small.
    for (chunk_i, chunk) in views.chunks(8).enumerate() {
        let cams: Vec<_> = chunk.iter().map(|&v| g_world.camera(v)).collect();
        let img = project(&gaussians, &cams, None, options).map_err(render_error)?;
        let data = super::host_values(&img);
        for (j, _) in chunk.iter().enumerate() {
            let dst = out.index_axis_mut(Axis(0), chunk_i * 8 + j);
            let src = &data[j * rows * cols..(j + 1) * rows * cols];
            for (d, s) in dst.into_iter().zip(src) {
                *d = s * f;
            }
        }
    }
    Ok(out)
}

/// A trained spectral model and its per-channel raw densities, for holdout predictions.
pub struct Holdout<'a> {
    pub model: &'a GaussianModel,
    pub raw: &'a Tensor<2>,
    pub world: &'a World,
    pub info: &'a ModelInfo,
}

/// Scores of one predicted (held-out) channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HoldoutScore {
    pub label: String,
    pub tau: f64,
    pub coordinate: f64,
    pub unit: String,
    /// 3-D PSNR / SSIM of the predicted volume (reference-max normalised), when references exist.
    pub volume_psnr: Option<f64>,
    pub volume_ssim: Option<f64>,
    /// Mean projection PSNR / SSIM over every view at which the channel was simulated.
    pub proj_psnr: Option<f64>,
    pub proj_ssim: Option<f64>,
    pub views: usize,
}

/// Predict the `held` channels of `full` by interpolation, score them, write `holdout.json`;
/// returns the predicted volumes (mm⁻¹) in `held` order.
pub fn score_holdout(
    h: &Holdout,
    full: &Scene,
    held: &[usize],
    out_dir: &Path,
) -> Result<Vec<Array3<f32>>> {
    let mut vols = Vec::new();
    let mut scores = Vec::new();
    for &c in held {
        let ch = &full.channels[c];
        let raw = raw_at(h.raw, h.info, ch.tau, Extrapolation::Refuse)
            .map_err(|e| e.under(&format!("holdout `{}`", ch.label)))?;
        let vol = volumes_with(h.model, raw.clone(), &full.geometry.volume, h.world)?
            .index_axis(Axis(0), 0)
            .to_owned();
        let (volume_psnr, volume_ssim) = match &full.references {
            Some(r) => {
                let (p, s) = score_volume(vol.clone(), &r.index_axis(Axis(0), c).to_owned())?;
                (Some(p), Some(s))
            }
            None => (None, None),
        };
        let views = full.views_with_channel(c);
        let (proj_psnr, proj_ssim) = if views.is_empty() {
            (None, None)
        } else {
            let pred = render_views(
                h.model,
                raw,
                h.world,
                &full.geometry,
                &views,
                &h.info.projection.options(),
            )?;
            let truth = full.channel_projections(c).select(Axis(0), &views);
            let (p, s) = projection_metrics(pred.view(), truth.view(), &SsimParams::default())?;
            (Some(p), Some(s))
        };
        scores.push(HoldoutScore {
            label: ch.label.clone(),
            tau: ch.tau,
            coordinate: ch.coordinate.value(),
            unit: ch.coordinate.unit().to_string(),
            volume_psnr,
            volume_ssim,
            proj_psnr,
            proj_ssim,
            views: views.len(),
        });
        vols.push(vol);
    }
    let path = out_dir.join(HOLDOUT_FILE);
    let json = serde_json::to_string_pretty(&scores)
        .map_err(|e| Error::field(&path, ".", e.to_string()))?;
    fs::write(&path, json + "\n").map_err(|e| Error::io(&path, e))?;
    for s in &scores {
        eprintln!(
            "held out {:>10}  volume PSNR {}  projection PSNR {} ({} views)",
            s.label,
            s.volume_psnr
                .map(|v| format!("{v:.2} dB"))
                .unwrap_or("–".into()),
            s.proj_psnr
                .map(|v| format!("{v:.2} dB"))
                .unwrap_or("–".into()),
            s.views
        );
    }
    Ok(vols)
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
    /// Open `<run_dir>/gaussians.safetensors`.
    pub fn open(run_dir: &Path, device: &Device) -> Result<Self> {
        let path = run_dir.join(MODEL_FILE);
        if !path.exists() {
            return Err(Error::invalid(
                "run_dir",
                format!(
                    "{} has no {MODEL_FILE}: queries need a spectral run (method 4dsg or \
                     4dsg-stage1); r2gs runs keep one independent model per channel",
                    run_dir.display()
                ),
            ));
        }
        let loaded = load_model(&path, device)?;
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
