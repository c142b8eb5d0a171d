//! A NAF run: one field per channel, fitted independently to that channel's training views.

use crate::Result;
use crate::evaluate::{Metrics, Reconstruction, TestProjector, metrics};
use crate::methods::naf::{ChannelTask, Checkpointed, NafCheckpoints, NafConfig, fit_channel};
use crate::record::RunDir;
use crate::record::fingerprint::Fingerprint;
use crate::record::log::RunLog;
use crate::setup::{RunOptions, Setup};
use ndarray::Axis;
use prism_domain::scene::Scene;

/// Fit every channel of `scene` into `dir`; the scores when the scene has references. With
/// `options.checkpoint` the run saves its state (`crate::methods::naf::resume`), or continues the saved
/// one: its finished channels' volumes are taken as they are.
pub(crate) fn run(
    config: &NafConfig,
    scene: &Scene,
    dir: &mut RunDir,
    options: &RunOptions,
) -> Result<Option<Metrics>> {
    config.validate()?;
    let setup = Setup::new(scene, Vec::new(), options)?;
    let mut log = RunLog::create(&dir.file(RunDir::LOG))?;
    let mut volumes = Vec::new();
    let mut start = None;
    let mut checkpoints = match &options.checkpoint {
        Some(c) => {
            let fingerprint = Fingerprint::new(config, scene, &[], &[])?;
            let mut ck = NafCheckpoints::new(c.file(config.checkpoint_every, fingerprint));
            if c.resume {
                let shape = scene.geometry.volume.shape_zyx();
                let saved = ck.read(scene.channels.len(), shape)?;
                log.restore(&saved.log)?;
                for (v, ch) in saved.finished.iter().zip(&scene.channels) {
                    dir.write_volume(&ch.label, v)?;
                }
                volumes = saved.finished;
                start = saved.current;
            }
            Some(ck)
        }
        None => None,
    };
    for (c, ch) in scene.channels.iter().enumerate().skip(volumes.len()) {
        let reference = scene.references.as_ref().map(|r| r.index_axis(Axis(0), c));
        let task = ChannelTask {
            label: &ch.label,
            index: c,
            projections: scene.channel_projections(c),
            views: &setup.views[c],
            reference,
            scoring: &setup.scoring,
        };
        let vol = fit_channel(
            config,
            &scene.geometry,
            &task,
            &options.device,
            &mut log,
            options.observer,
            checkpoints.as_mut().map(|checkpoints| Checkpointed {
                checkpoints,
                finished: &volumes,
                start: start.take(),
            }),
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
