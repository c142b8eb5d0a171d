//! R²-Gaussian (`method: r2gs`): every observed channel reconstructed independently by its own
//! set of 3D Gaussians, initialised from the channel's FDK ([`crate::init`]) and trained by the
//! shared Gaussian loop ([`crate::gaussians::train`]). Its configuration ([`config`]) is the
//! geometry stage's alone; checkpoints are the shared
//! [`crate::gaussians::train::Checkpoints`]; the run around it is [`crate::pipeline`]'s, and it ends
//! as every Gaussian run does ([`crate::gaussians::finish`]: volumes, `train.json`, scores).

pub mod config;

pub use config::R2gsConfig;

use crate::Result;
use crate::gaussians::io::{ModelInfo, save_model, write_ply};
use crate::gaussians::train::Evaluator;
use crate::gaussians::train::data::image;
use crate::gaussians::train::{Journal, Stage, Supervision};
use crate::gaussians::volume::volumes;
use crate::gaussians::{GaussianModel, World};
use crate::init::initial_model;
use crate::record::RunDir;
use crate::setup::{Setup, Volumes};
use burn::tensor::Device;
use ndarray::Axis;

/// R²-Gaussian: every observed channel trained independently; its model saved as
/// `gaussians-<label>`.
pub(crate) fn train(
    config: &R2gsConfig,
    setup: &Setup,
    dir: &mut RunDir,
    device: &Device,
    journal: &mut Journal,
) -> Result<(Volumes, Vec<(GaussianModel, World)>)> {
    let config = &config.geometry;
    let scene = &*setup.observed;
    let geometry = &scene.geometry;
    let mut out = Vec::new();
    let mut models = Vec::new();
    let labels: Vec<&str> = scene.channels.iter().map(|c| c.label.as_str()).collect();
    let tv_weights = config.loss.channel_tv_weights(&labels)?;
    for (c, ch) in scene.channels.iter().enumerate() {
        let views = &setup.views[c];
        let proj = scene.channel_projections(c);
        let (mut model, world) = initial_model(config, geometry, proj, views, device)
            .map_err(|e| e.under(&format!("channels[{c}]")))?;
        let images = views.iter().map(|&v| image(proj, v)).collect();
        let sup = Supervision::single(geometry, &world, views, images, device);
        let eval = scene.references.as_ref().map(|r| Evaluator {
            scoring: setup.scoring.clone(),
            grid: geometry.volume.clone(),
            world,
            references: vec![r.index_axis(Axis(0), c).to_owned()],
        });
        let stage = Stage {
            tv_weights: vec![tv_weights[c]],
            ..Stage::geometry(config, "r2gs", &ch.label, &geometry.volume, &world)
        };
        journal.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
        let stem = RunDir::stem(&ch.label);
        let info = ModelInfo::new(setup.full, scene, &[c], config.projection);
        save_model(
            &dir.file(&format!("gaussians-{stem}.safetensors")),
            &model,
            None,
            &world,
            &info,
        )?;
        write_ply(
            &dir.file(&format!("gaussians-{stem}.ply")),
            &model,
            None,
            &world,
            &info.channels,
        )?;
        let v = volumes(&model, &geometry.volume, &world)?;
        out.push(v.index_axis(Axis(0), 0).to_owned());
        models.push((model, world));
    }
    Ok((out, models))
}
