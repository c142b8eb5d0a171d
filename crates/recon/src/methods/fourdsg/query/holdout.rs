//! Channels held out of training, predicted by the trained curves (interpolated in raw density
//! along the spectral axis) or, for a basis-head run, by the physics (the materials' attenuation
//! in the held-out channel), and scored against what the scene knows of them (their reference
//! volume, their projections at every view): the contents of `holdout.json`.

use super::raw_at;
use crate::Result;
use crate::evaluate::{Evaluation, Scores, score};
use crate::gaussians::io::ModelInfo;
use crate::gaussians::volume::render_views;
use crate::gaussians::volume::volumes_with;
use crate::gaussians::{GaussianModel, World};
use crate::methods::fourdsg::heads::BasisHead;
use crate::record::RunDir;
use burn::tensor::Tensor;
use ndarray::{Array3, Axis};
use prism_domain::decompose::channel_specs;
use prism_domain::metrics::{SsimParams, projection_metrics};
use prism_domain::scene::Scene;
use prism_gscnet::Extrapolation;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A trained spectral model and its per-channel raw densities, for holdout predictions.
pub struct Holdout<'a> {
    pub model: &'a GaussianModel,
    pub raw: &'a Tensor<2>,
    pub world: &'a World,
    pub info: &'a ModelInfo,
    /// The basis head of a basis-head run (`model`'s densities are then its basis columns).
    pub basis: Option<&'a BasisHead>,
}

/// How a held-out channel was predicted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Predictor {
    /// Raw densities interpolated between the neighbouring trained channels' (the default, and
    /// what files written before the field existed hold).
    #[default]
    Interpolation,
    /// The basis materials' attenuation in the held-out channel ([`BasisHead::unseen_raw`]).
    Physics,
}

/// Scores of one predicted (held-out) channel: an entry of `holdout.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HoldoutScore {
    pub label: String,
    pub tau: f64,
    pub coordinate: f64,
    pub unit: String,
    #[serde(default)]
    pub predictor: Predictor,
    /// The predicted volume's scores against its reference (the run's protocol), when the
    /// scene has references.
    pub volume: Option<Scores>,
    /// Mean projection PSNR / SSIM over every view at which the channel was simulated.
    #[serde(with = "prism_domain::metrics::score_json::option", default)]
    pub proj_psnr: Option<f64>,
    #[serde(with = "prism_domain::metrics::score_json::option", default)]
    pub proj_ssim: Option<f64>,
    pub views: usize,
}

/// Predict the `held` channels of `full` (by the physics for a basis-head run, else by
/// interpolation) and score them: the predicted volumes (mm⁻¹) and the scores, in `held` order.
pub fn predict_holdout(
    h: &Holdout,
    full: &Scene,
    held: &[usize],
    eval: &Evaluation,
) -> Result<(Vec<Array3<f32>>, Vec<HoldoutScore>)> {
    let specs = match h.basis {
        Some(_) => Some(channel_specs(full)?.0),
        None => None,
    };
    let roi = eval.roi(full)?;
    let mut vols = Vec::new();
    let mut scores = Vec::new();
    for &c in held {
        let ch = &full.channels[c];
        let (raw, predictor) = match (h.basis, &specs) {
            (Some(head), Some(specs)) => (head.unseen_raw(&specs[c], h.model), Predictor::Physics),
            _ => (
                raw_at(h.raw, h.info, ch.tau, Extrapolation::Refuse),
                Predictor::Interpolation,
            ),
        };
        let raw = raw.map_err(|e| e.under(&format!("holdout `{}`", ch.label)))?;
        let vol = volumes_with(h.model, raw.clone(), &full.geometry.volume, h.world)?
            .index_axis(Axis(0), 0)
            .to_owned();
        let volume = match &full.references {
            Some(r) => Some(score(
                vol.view(),
                r.index_axis(Axis(0), c),
                eval,
                roi.as_ref(),
            )?),
            None => None,
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
            predictor,
            volume,
            proj_psnr,
            proj_ssim,
            views: views.len(),
        });
        vols.push(vol);
    }
    Ok((vols, scores))
}

/// The scores of the channels a finished run `dir` predicted without training data
/// (`holdout.json`; none when the run held nothing out).
pub fn read_scores(dir: &Path) -> Result<Vec<HoldoutScore>> {
    let path = dir.join(RunDir::HOLDOUT);
    if path.exists() {
        RunDir::read_json(&path)
    } else {
        Ok(Vec::new())
    }
}
