//! A NAF run: one field per channel, fitted independently to that channel's training views.

use super::run_dir::RunDir;
use super::setup::{RunOptions, Setup};
use crate::Result;
use crate::evaluate::{Metrics, Reconstruction, TestProjector, metrics};
use crate::naf::{ChannelTask, NafConfig, fit_channel};
use crate::train::log::RunLog;
use ndarray::Axis;
use prism_domain::scene::Scene;

/// Fit every channel of `scene` into `dir`; the scores when the scene has references.
pub(super) fn run(
    config: &NafConfig,
    scene: &Scene,
    dir: &mut RunDir,
    options: &RunOptions,
) -> Result<Option<Metrics>> {
    config.validate()?;
    let setup = Setup::new(scene, Vec::new(), options.observer)?;
    let mut log = RunLog::create(&dir.file(RunDir::LOG))?;
    let mut volumes = Vec::new();
    for (c, ch) in scene.channels.iter().enumerate() {
        let reference = scene.references.as_ref().map(|r| r.index_axis(Axis(0), c));
        let task = ChannelTask {
            label: &ch.label,
            index: c,
            projections: scene.channel_projections(c),
            views: &setup.views[c],
            reference,
        };
        let vol = fit_channel(
            config,
            &scene.geometry,
            &task,
            &options.device,
            &mut log,
            options.observer,
        )
        .map_err(|e| e.under(&format!("channels[{c}]")))?;
        dir.write_volume(&ch.label, &vol)?;
        volumes.push(vol);
    }
    metrics(
        scene,
        &Reconstruction {
            method: "naf",
            volumes: &volumes,
            views: &setup.views,
            wall_s: log.train_s(),
            unseen: setup.unseen,
            projector: TestProjector::Reproject,
        },
        options.evaluation,
    )
}
