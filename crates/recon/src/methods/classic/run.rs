//! A classic method's run: every channel reconstructed from its training views, independently
//! or (`tv`) jointly.

use super::{ClassicConfig, ClassicMethod, reconstruct_channel, reconstruct_jointly};
use crate::Result;
use crate::evaluate::{Metrics, Reconstruction, TestProjector, metrics};
use crate::record::RunDir;
use crate::setup::{RunOptions, Setup};
use prism_domain::scene::Scene;
use std::time::Instant;

/// Reconstruct every channel of `scene` into `dir`; the scores when the scene has references.
pub(crate) fn run(
    config: &ClassicConfig,
    scene: &Scene,
    dir: &mut RunDir,
    options: &RunOptions,
) -> Result<Option<Metrics>> {
    let observer = options.observer;
    config.validate()?;
    let setup = Setup::new(scene, Vec::new(), options)?;
    let iters = config.resolved_iterations();
    let start = Instant::now();
    let volumes = if config.method == ClassicMethod::Tv {
        let labels: Vec<&str> = scene.channels.iter().map(|c| c.label.as_str()).collect();
        // With a guide, its reconstruction runs first, as many iterations again.
        let (kind, steps) = match config.tv.guide {
            Some(_) => ("directional ", 2 * iters),
            None => ("", iters),
        };
        observer.phase(
            &format!(
                "tv ({kind}{}) {}",
                config.tv.coupling.name(),
                labels.join(", ")
            ),
            steps as u64,
        );
        let projections: Vec<_> = (0..scene.channels.len())
            .map(|c| scene.channel_projections(c))
            .collect();
        let volumes = reconstruct_jointly(
            config,
            &scene.geometry,
            &projections,
            &setup.views,
            &scene.channel_ratios(scene.train_views()),
            &mut |i| observer.progress(i as u64, ""),
        )?;
        for (ch, vol) in scene.channels.iter().zip(&volumes) {
            dir.write_volume(&ch.label, vol)?;
        }
        volumes
    } else {
        let mut volumes = Vec::new();
        for (c, ch) in scene.channels.iter().enumerate() {
            observer.phase(
                &format!("{} {}", config.method.name(), ch.label),
                iters as u64,
            );
            let vol = reconstruct_channel(
                config,
                &scene.geometry,
                scene.channel_projections(c),
                &setup.views[c],
                &mut |i| observer.progress(i as u64, ""),
            )
            .map_err(|e| e.under(&format!("channels[{c}]")))?;
            dir.write_volume(&ch.label, &vol)?;
            volumes.push(vol);
        }
        volumes
    };
    let wall_s = start.elapsed().as_secs_f64();
    metrics(
        scene,
        &Reconstruction {
            method: config.method.name(),
            volumes: &volumes,
            views: &setup.views,
            wall_s,
            unseen: setup.unseen,
            projector: TestProjector::Reproject,
        },
        options.evaluation,
    )
}
