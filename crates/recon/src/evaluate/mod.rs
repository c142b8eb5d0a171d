//! Reconstructed volumes scored against the scene's references: the contents of
//! `metrics.json` ([`Metrics`]) and the scores a training stage logs as it goes ([`Evaluator`]).
//!
//! Protocol (R²-Gaussian's): prediction and reference are divided by the reference's maximum;
//! PSNR over the whole 3-D volume with peak 1; 3-D SSIM (zero-padded window, data range 1), and
//! for reference scikit-image's border convention. Projection metrics re-project the volume with
//! the Joseph projector at the scene's test views (R²-Gaussian's `metric_proj`).

use crate::gaussian::GaussianModel;
use crate::gaussian::World;
use crate::gaussian::volume::{volumes, volumes_with};
use crate::{Error, Result};
use burn::tensor::Tensor;
use ndarray::{Array3, Array4, ArrayView3, Axis};
use prism_domain::geometry::VolumeGrid;
use prism_domain::metrics::{Border, SsimParams, projection_metrics, psnr, ssim_3d};
use prism_domain::projector::Joseph;
use prism_domain::scene::{Scene, SpectralCoordinate};
use serde::{Deserialize, Serialize};

/// Scores of one channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelMetrics {
    pub label: String,
    pub coordinate: SpectralCoordinate,
    /// Number of training views the channel was reconstructed from.
    pub views: usize,
    /// 3-D PSNR (dB) and SSIM (R²-Gaussian, zero-padded window) of the normalised volume.
    pub psnr: f64,
    pub ssim: f64,
    /// 3-D SSIM with scikit-image's border convention (interior of each slice), for reference.
    pub ssim_skimage: f64,
    /// Mean projection PSNR/SSIM over the test views (absent when the channel has none).
    pub proj_psnr: Option<f64>,
    pub proj_ssim: Option<f64>,
}

/// Mean over channels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeanMetrics {
    pub psnr: f64,
    pub ssim: f64,
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
    /// How volumes were normalised before scoring.
    pub normalisation: String,
    /// Fraction of voxels seen by no ray (0 for a fully covered grid).
    pub unseen_fraction: f64,
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
}

/// The reference's peak: the divisor of prediction and reference (an error when not positive).
fn peak(truth: ArrayView3<f32>, what: &str) -> Result<f32> {
    let peak = truth.fold(0.0f32, |a, &b| a.max(b));
    if peak <= 0.0 {
        return Err(Error::invalid(
            "references",
            format!("{what}: the reference volume has no positive value"),
        ));
    }
    Ok(peak)
}

/// Score `r` against the references of `scene` (whose channels are `r`'s); `None` when the
/// scene has none.
pub fn metrics(scene: &Scene, r: &Reconstruction) -> Result<Option<Metrics>> {
    let Some(refs) = &scene.references else {
        return Ok(None);
    };
    let mut channels = Vec::new();
    for (c, ch) in scene.channels.iter().enumerate() {
        let truth = refs.index_axis(Axis(0), c);
        let peak = peak(truth, &format!("channel `{}`", ch.label))?;
        let t = truth.mapv(|x| x / peak);
        let p = r.volumes[c].mapv(|x| x / peak);
        let zero_pad = SsimParams::default();
        let crop = SsimParams {
            border: Border::Crop,
            ..zero_pad
        };
        let (proj_psnr, proj_ssim) = match test_projection_metrics(scene, c, &r.volumes[c])? {
            Some((a, b)) => (Some(a), Some(b)),
            None => (None, None),
        };
        channels.push(ChannelMetrics {
            label: ch.label.clone(),
            coordinate: ch.coordinate.clone(),
            views: r.views[c].len(),
            psnr: psnr(p.view(), t.view(), 1.0)?,
            ssim: ssim_3d(p.view(), t.view(), &zero_pad)?.mean,
            ssim_skimage: ssim_3d(p.view(), t.view(), &crop)?.mean,
            proj_psnr,
            proj_ssim,
        });
    }
    let n = channels.len() as f64;
    Ok(Some(Metrics {
        method: r.method.to_string(),
        scene: scene.name.clone(),
        wall_s: r.wall_s,
        mean: MeanMetrics {
            psnr: channels.iter().map(|c| c.psnr).sum::<f64>() / n,
            ssim: channels.iter().map(|c| c.ssim).sum::<f64>() / n,
        },
        channels,
        normalisation: "prediction and reference divided by the reference's maximum; PSNR peak 1, SSIM data range 1".into(),
        unseen_fraction: r.unseen,
    }))
}

/// Projection metrics of channel `c` on the scene's available test views, if any.
fn test_projection_metrics(
    scene: &Scene,
    c: usize,
    vol: &Array3<f32>,
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
    let a = Joseph::new(&scene.geometry)?;
    let pred = a.forward_views(vol.view(), &views)?;
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

/// PSNR / SSIM (R²-Gaussian conventions) of `pred` against `truth`, both divided by the
/// reference's maximum.
pub fn score_volume(pred: Array3<f32>, truth: &Array3<f32>) -> Result<(f64, f64)> {
    let peak = peak(truth.view(), "a channel")?;
    let t = truth.mapv(|x| x / peak);
    let p = pred.mapv(|x| x / peak);
    Ok((
        psnr(p.view(), t.view(), 1.0)?,
        ssim_3d(p.view(), t.view(), &SsimParams::default())?.mean,
    ))
}

/// Reference volumes to score a model against during training.
pub struct Evaluator {
    /// Reconstruction grid (millimetres) and the world the model lives in.
    pub grid: VolumeGrid,
    pub world: World,
    /// One reference (mm⁻¹, `[z][y][x]`) per density column.
    pub references: Vec<Array3<f32>>,
}

impl Evaluator {
    /// Mean PSNR / SSIM over columns, after dividing both volumes by the reference's maximum.
    pub fn score(&self, model: &GaussianModel) -> Result<(f64, f64)> {
        self.score_volumes(volumes(model, &self.grid, &self.world)?)
    }

    /// [`Evaluator::score`] with the model's densities replaced by raw columns `[K, M]`.
    pub fn score_raw(&self, model: &GaussianModel, raw: Tensor<2>) -> Result<(f64, f64)> {
        self.score_volumes(volumes_with(model, raw, &self.grid, &self.world)?)
    }

    fn score_volumes(&self, vols: Array4<f32>) -> Result<(f64, f64)> {
        let (mut p, mut s) = (0.0, 0.0);
        for (c, truth) in self.references.iter().enumerate() {
            let (a, b) = score_volume(vols.index_axis(Axis(0), c).to_owned(), truth)?;
            p += a;
            s += b;
        }
        let n = self.references.len().max(1) as f64;
        Ok((p / n, s / n))
    }
}
