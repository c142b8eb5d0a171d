//! Reconstructed volumes scored against the scene's references: the contents of
//! `metrics.json` ([`Metrics`]) under an evaluation [`protocol`], and the scores a training stage
//! logs as it goes ([`Evaluator`]). `docs/metrics.md` describes the protocol and every field.
//!
//! Projection metrics (R²-Gaussian's `metric_proj`) compare the scene's test views with
//! projections of the reconstruction: Joseph re-projections of the volume for the classic
//! methods, the Gaussian renderer itself for the Gaussian methods ([`TestProjector`]).

pub mod lpips;
pub mod protocol;

pub use protocol::{Evaluation, Protocol, ProtocolRecord, Scores, SliceAxes, score};

use crate::record::RunDir;
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3, Axis};
use prism_domain::metrics::{Roi, SsimParams, projection_metrics, psnr, score_json, ssim_3d};
use prism_domain::projector::Joseph;
use prism_domain::scene::{Scene, SpectralCoordinate};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;

/// Scores of one channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelMetrics {
    pub label: String,
    pub coordinate: SpectralCoordinate,
    /// Number of training views the channel was reconstructed from.
    pub views: usize,
    #[serde(flatten)]
    pub scores: Scores,
    /// Mean projection PSNR/SSIM over the test views (absent when the channel has none).
    #[serde(with = "score_json::option", default)]
    pub proj_psnr: Option<f64>,
    #[serde(with = "score_json::option", default)]
    pub proj_ssim: Option<f64>,
}

/// Means over channels (written as [`Scores`] are: `"inf"` for an infinite PSNR).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeanMetrics {
    #[serde(with = "score_json")]
    pub psnr: f64,
    #[serde(with = "score_json")]
    pub ssim: f64,
    #[serde(with = "score_json")]
    pub psnr_slices: f64,
    #[serde(with = "score_json")]
    pub ssim_slices: f64,
    #[serde(with = "score_json::option", default)]
    pub lpips: Option<f64>,
}

impl MeanMetrics {
    /// The means of `channels`' scores (LPIPS only when every channel has one).
    pub fn of(channels: &[ChannelMetrics]) -> MeanMetrics {
        let n = channels.len() as f64;
        let mean = |f: fn(&Scores) -> f64| channels.iter().map(|c| f(&c.scores)).sum::<f64>() / n;
        let lpips: Option<Vec<f64>> = channels.iter().map(|c| c.scores.lpips).collect();
        MeanMetrics {
            psnr: mean(|s| s.psnr),
            ssim: mean(|s| s.ssim),
            psnr_slices: mean(|s| s.psnr_slices),
            ssim_slices: mean(|s| s.ssim_slices),
            lpips: lpips.map(|v| v.iter().sum::<f64>() / n),
        }
    }
}

/// Contents of `metrics.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub method: String,
    pub scene: String,
    /// Reconstruction wall time of all channels, seconds (metrics excluded; training time for
    /// the Gaussian methods).
    pub wall_s: f64,
    pub channels: Vec<ChannelMetrics>,
    pub mean: MeanMetrics,
    /// How the volumes were scored.
    pub protocol: ProtocolRecord,
    /// Fraction of voxels seen by no ray (0 for a fully covered grid).
    pub unseen_fraction: f64,
}

/// A renderer of test views: `(channel, views)` → line integrals `[view][row][col]`.
pub type RenderFn<'a> = &'a dyn Fn(usize, &[usize]) -> Result<Array3<f32>>;

/// How the test views of a channel are projected for the projection metrics.
pub enum TestProjector<'a> {
    /// Joseph re-projection of the reconstructed volume.
    Reproject,
    /// The method's own renderer: `render(channel, views)` gives line integrals
    /// `[view][row][col]`; `what` names it in `metrics.json`.
    Render { what: String, render: RenderFn<'a> },
}

/// What was reconstructed, for [`Metrics`].
pub struct Reconstruction<'a> {
    pub method: &'a str,
    /// One volume per channel of the scene (mm⁻¹, `[z][y][x]`).
    pub volumes: &'a [Array3<f32>],
    /// Training views per channel.
    pub views: &'a [Vec<usize>],
    pub wall_s: f64,
    pub unseen: f64,
    pub projector: TestProjector<'a>,
}

/// Score `r` against the references of `scene` (whose channels are `r`'s) under `eval`; `None`
/// when the scene has none.
pub fn metrics(scene: &Scene, r: &Reconstruction, eval: &Evaluation) -> Result<Option<Metrics>> {
    let Some(refs) = &scene.references else {
        return Ok(None);
    };
    let roi = eval.roi(scene)?;
    let mut channels = Vec::new();
    for (c, ch) in scene.channels.iter().enumerate() {
        let scores = score(
            r.volumes[c].view(),
            refs.index_axis(Axis(0), c),
            eval,
            roi.as_ref(),
        )
        .map_err(|e| e.under(&format!("channel `{}`", ch.label)))?;
        let (proj_psnr, proj_ssim) = match test_projection_metrics(scene, c, r)? {
            Some((a, b)) => (Some(a), Some(b)),
            None => (None, None),
        };
        channels.push(ChannelMetrics {
            label: ch.label.clone(),
            coordinate: ch.coordinate.clone(),
            views: r.views[c].len(),
            scores,
            proj_psnr,
            proj_ssim,
        });
    }
    let projections = match &r.projector {
        TestProjector::Reproject => "Joseph re-projection of the reconstructed volume".to_string(),
        TestProjector::Render { what, .. } => what.clone(),
    };
    Ok(Some(Metrics {
        method: r.method.to_string(),
        scene: scene.name.clone(),
        wall_s: r.wall_s,
        mean: MeanMetrics::of(&channels),
        channels,
        protocol: eval.record(r.volumes[0].shape(), &projections, roi.as_ref()),
        unseen_fraction: r.unseen,
    }))
}

/// Score the volumes of the finished run in `dir` again under `eval` (a changed protocol: the
/// region of interest, the grid, the slices) and replace its `metrics.json`, keeping what the
/// protocol does not touch (test-view projection metrics, times, the unseen fraction). Refused
/// for a run with held-out channels (their volumes are not kept) or without references.
pub fn rescore(dir: &Path, scene: &Scene, eval: &Evaluation) -> Result<Metrics> {
    if dir.join(RunDir::HOLDOUT).exists() {
        return Err(Error::invalid(
            "run_dir",
            format!(
                "{} has held-out channels, whose predicted volumes are not kept: run it again",
                dir.display()
            ),
        ));
    }
    let Some(refs) = &scene.references else {
        return Err(Error::invalid(
            "references",
            "the scene has none to score against",
        ));
    };
    let path = dir.join(RunDir::METRICS);
    let old: Metrics = RunDir::read_json(&path)?;
    let roi = eval.roi(scene)?;
    let shape = scene.geometry.volume.shape_zyx();
    let mut channels = Vec::new();
    for ch in &old.channels {
        let c = scene
            .channels
            .iter()
            .position(|s| s.label == ch.label)
            .ok_or_else(|| {
                Error::field(
                    &path,
                    "channels",
                    format!("channel `{}` is not the scene's", ch.label),
                )
            })?;
        let file = dir.join(RunDir::volume_file(&ch.label));
        let vol: Array3<f32> = prism_domain::scene::npy::read_array(&file, "volume")?;
        prism_domain::error::ensure_shape("volume", vol.shape(), &shape, "the scene's grid")
            .map_err(|e| Error::from(e).in_file(&file))?;
        let scores = score(vol.view(), refs.index_axis(Axis(0), c), eval, roi.as_ref())
            .map_err(|e| e.under(&format!("channel `{}`", ch.label)))?;
        channels.push(ChannelMetrics {
            scores,
            ..ch.clone()
        });
    }
    let metrics = Metrics {
        mean: MeanMetrics::of(&channels),
        channels,
        protocol: eval.record(&shape, &old.protocol.projections, roi.as_ref()),
        ..old
    };
    RunDir::replace_json(&path, &metrics)?;
    Ok(metrics)
}

/// Projection metrics of channel `c` on the scene's available test views, if any.
fn test_projection_metrics(
    scene: &Scene,
    c: usize,
    r: &Reconstruction,
) -> Result<Option<(f64, f64)>> {
    let views: Vec<usize> = scene
        .test_views()
        .iter()
        .copied()
        .filter(|&v| scene.availability[[v, c]])
        .collect();
    if views.is_empty() {
        return Ok(None);
    }
    let pred = match &r.projector {
        TestProjector::Reproject => {
            Joseph::new(&scene.geometry)?.forward_views(r.volumes[c].view(), &views)?
        }
        TestProjector::Render { render, .. } => render(c, &views)?,
    };
    let truth = scene.channel_projections(c).select(Axis(0), &views);
    if truth.iter().all(|&x| x <= 0.0) {
        return Ok(None);
    }
    Ok(Some(projection_metrics(
        pred.view(),
        truth.view(),
        &SsimParams::default(),
    )?))
}

/// How a training curve (`log.jsonl`'s `psnr`, `ssim`) scores a volume: over the whole grid
/// ([`score_volume`]), or, where the run's final metrics are taken inside an object mask
/// ([`Evaluation::roi`]), inside that mask as they are ([`score`], without LPIPS), so that a
/// curve read at its last point agrees with `metrics.json` (the suite's equal-time table reads
/// one method off its curve and the other off its metrics).
#[derive(Clone, Default)]
pub struct CurveScoring(Option<Arc<(Evaluation, Roi)>>);

impl CurveScoring {
    /// The scoring of runs on `scene` under `eval`.
    pub fn of(eval: &Evaluation, scene: &Scene) -> Result<Self> {
        let inside = eval.roi(scene)?;
        Ok(CurveScoring(
            inside.map(|roi| Arc::new((eval.without_lpips(), roi))),
        ))
    }

    /// PSNR / SSIM of `pred` against `truth` (mm⁻¹, `[z][y][x]`).
    pub fn score(&self, pred: ArrayView3<f32>, truth: ArrayView3<f32>) -> Result<(f64, f64)> {
        match &self.0 {
            None => score_volume(pred, truth),
            Some(inside) => {
                let s = score(pred, truth, &inside.0, Some(&inside.1))?;
                Ok((s.psnr, s.ssim))
            }
        }
    }
}

/// PSNR / SSIM (R²-Gaussian conventions) of `pred` against `truth`, both divided by the
/// reference's maximum: the scores a training stage logs over the whole grid.
pub fn score_volume(pred: ArrayView3<f32>, truth: ArrayView3<f32>) -> Result<(f64, f64)> {
    let peak = truth.fold(0.0f32, |a, &b| a.max(b));
    if peak <= 0.0 {
        return Err(Error::invalid(
            "references",
            "a reference volume has no positive value",
        ));
    }
    let t = truth.mapv(|x| x / peak);
    let p = pred.mapv(|x| x / peak);
    Ok((
        psnr(p.view(), t.view(), 1.0)?,
        ssim_3d(p.view(), t.view(), &SsimParams::default())?.mean,
    ))
}
