//! What every Gaussian run ends with, whichever method trained it: every channel's volume
//! (observed channels fitted, held-out ones predicted), `train.json`, and the scores of the
//! observed channels, their test views rendered from the trained models ([`Trained`]).

use crate::evaluate::{Evaluation, Metrics, Reconstruction, TestProjector, metrics};
use crate::gaussians::train::{Journal, StageReport};
use crate::gaussians::volume::render_views;
use crate::gaussians::{GaussianModel, ProjectionConfig, World};
use crate::record::RunDir;
use crate::setup::{Setup, Volumes};
use crate::{Error, Result};
use burn::tensor::Tensor;
use ndarray::Array3;
use prism_domain::geometry::Geometry;
use prism_render::ProjectOptions;
use serde::Serialize;

/// The trained models of a run, kept to render its test views.
pub(crate) enum Trained {
    /// R²-Gaussian: one model (and world) per observed channel.
    PerChannel(Vec<(GaussianModel, World)>),
    /// One shared model with a raw density column per observed channel (4D-SG).
    Shared(Box<SharedModel>),
}

/// A model whose Gaussians every channel shares, with the raw density column of each.
pub(crate) struct SharedModel {
    pub model: GaussianModel,
    /// Raw densities `[K, M]`, one column per observed channel.
    pub raw: Tensor<2>,
    pub world: World,
}

impl Trained {
    /// Line integrals `[view][row][col]` of observed channel `c` at `views` of `geometry`.
    fn render(
        &self,
        geometry: &Geometry,
        options: &ProjectOptions,
        c: usize,
        views: &[usize],
    ) -> Result<Array3<f32>> {
        match self {
            Trained::PerChannel(m) => {
                let (model, world) = &m[c];
                render_views(
                    model,
                    model.densities.value.clone(),
                    world,
                    geometry,
                    views,
                    options,
                )
            }
            Trained::Shared(s) => {
                let raw = s.raw.clone().narrow(1, c, 1);
                render_views(&s.model, raw, &s.world, geometry, views, options)
            }
        }
    }
}

/// Contents of `train.json`.
#[derive(Serialize)]
struct TrainSummary<'a> {
    method: &'a str,
    scene: &'a str,
    wall_s: f64,
    train_s: f64,
    stages: &'a [StageReport],
}

/// What a Gaussian run produced.
pub(crate) struct Outputs {
    pub observed: Volumes,
    /// The held-out channels' predictions (4D-SG with `holdout_channels`).
    pub predicted: Option<Volumes>,
    pub trained: Trained,
}

/// Write `train.json` and every channel's volume (observed ones fitted, held-out ones
/// predicted); the scores of the observed channels (held-out ones are in `holdout.json`).
pub(crate) fn finish(
    method: &'static str,
    projection: &ProjectionConfig,
    setup: &Setup,
    dir: &mut RunDir,
    journal: &mut Journal,
    out: Outputs,
    eval: &Evaluation,
) -> Result<Option<Metrics>> {
    let train_s = journal.log.train_s();
    let summary = TrainSummary {
        method,
        scene: &setup.full.name,
        wall_s: journal.log.wall_s(),
        train_s,
        stages: &journal.stages,
    };
    dir.write_json(RunDir::TRAIN, &summary)?;
    let mut next_observed = out.observed.into_iter();
    let mut next_held = out.predicted.into_iter().flatten();
    let mut fitted = Vec::new();
    for (c, ch) in setup.full.channels.iter().enumerate() {
        let held = setup.held.contains(&c);
        let v = if held {
            next_held.next()
        } else {
            next_observed.next()
        }
        .ok_or_else(|| Error::invalid("channels", "one volume per channel"))?;
        dir.write_volume(&ch.label, &v)?;
        if !held {
            fitted.push(v);
        }
    }
    let options = projection.options();
    let geometry = &setup.observed.geometry;
    let render = |c: usize, views: &[usize]| out.trained.render(geometry, &options, c, views);
    metrics(
        &setup.observed,
        &Reconstruction {
            method,
            volumes: &fitted,
            views: &setup.views,
            wall_s: train_s,
            unseen: setup.unseen,
            projector: TestProjector::Render {
                what: format!(
                    "the Gaussian renderer ({} projection) from the trained model",
                    projection.mode.name()
                ),
                render: &render,
            },
        },
        eval,
    )
}
