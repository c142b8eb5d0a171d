//! A Gaussian method's run: `r2gs` (R²-Gaussian per channel: init → train), `4dsg-stage1` and
//! `4dsg` (stage 1's shared geometry, trained or continued from its checkpoint → the spectral
//! stage → held-out channels predicted), then the models, volumes and `train.json`.

use super::run_dir::RunDir;
use super::setup::{RunOptions, Setup};
use crate::evaluate::{Evaluation, Evaluator, Metrics, Reconstruction, TestProjector, metrics};
use crate::gaussian::io::{ModelInfo, save_model, write_ply};
use crate::gaussian::volume::{volumes, volumes_with};
use crate::gaussian::{GaussianConfig, GaussianMethod, GaussianModel, World};
use crate::init::initial_model;
use crate::query::{Holdout, predict_holdout, render_views};
use crate::stage1::checkpoint::{self, Checkpoint};
use crate::stage1::{SharedGeometry, train_shared_geometry};
use crate::stage2::{Spectral, train_spectral};
use crate::train::data::image;
use crate::train::fingerprint::Fingerprint;
use crate::train::{Checkpoints, Journal, RunLog, Stage, StageReport, Supervision};
use crate::{Error, Result};
use burn::tensor::Device;
use ndarray::{Array3, Axis};
use prism_domain::geometry::Geometry;
use prism_domain::observe::{Level, Observer};
use prism_domain::scene::Scene;
use prism_render::ProjectOptions;
use serde::Serialize;
use std::path::Path;

/// One volume per channel (mm⁻¹, `[z][y][x]`).
pub(super) type Volumes = Vec<Array3<f32>>;

/// The trained models of a run, kept to render its test views.
pub(super) enum Trained {
    /// R²-Gaussian: one model (and world) per observed channel.
    PerChannel(Vec<(GaussianModel, World)>),
    /// 4D-SG: one model with a raw density column per observed channel.
    Spectral(Box<Spectral>),
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
            Trained::Spectral(s) => {
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

/// Run a Gaussian method on `scene` into `dir` (see the module docs).
pub(super) fn run(
    config: &GaussianConfig,
    scene: &Scene,
    dir: &mut RunDir,
    options: &RunOptions,
) -> Result<Option<Metrics>> {
    config.validate()?;
    let setup = Setup::new(scene, config.holdout_indices(scene)?, options.observer)?;
    let device = &options.device;
    let checkpoints = checkpoints(config, scene, options)?;
    let (mut journal, observed, predicted, trained) = match config.method {
        GaussianMethod::R2gs => {
            let mut journal =
                Journal::new(RunLog::create(&dir.file(RunDir::LOG))?, options.observer);
            journal.checkpoints = checkpoints;
            let (observed, models) = r2gs(config, &setup, dir, device, &mut journal)?;
            (journal, observed, None, Trained::PerChannel(models))
        }
        GaussianMethod::Stage1 | GaussianMethod::FourDsg => {
            let (mut journal, shared) = shared_geometry(
                config,
                &setup,
                dir,
                device,
                options.from_geometry,
                options.observer,
                checkpoints,
            )?;
            let (observed, predicted, s) = spectral(
                config,
                &setup,
                shared,
                dir,
                device,
                &mut journal,
                options.evaluation,
            )?;
            (journal, observed, predicted, Trained::Spectral(Box::new(s)))
        }
    };
    let out = Outputs {
        observed,
        predicted,
        trained,
    };
    finish(config, &setup, dir, &mut journal, out, options.evaluation)
}

/// What a Gaussian run produced.
pub(super) struct Outputs {
    pub observed: Volumes,
    /// The held-out channels' predictions (4D-SG with `holdout_channels`).
    pub predicted: Option<Volumes>,
    pub trained: Trained,
}

/// The run's checkpoints, when `options` ask for them: saved with the run's fingerprint (the
/// scene, the settings, and whether stage 1 came from a stage-1 checkpoint), and read back
/// when resuming.
fn checkpoints<'a>(
    config: &GaussianConfig,
    scene: &Scene,
    options: &RunOptions<'a>,
) -> Result<Option<Checkpoints<'a>>> {
    let Some(c) = &options.checkpoint else {
        return Ok(None);
    };
    let from_geometry = serde_json::Value::Bool(options.from_geometry.is_some());
    let fingerprint = Fingerprint::new(config, scene, &[], &[("from_geometry", from_geometry)])?;
    let checkpoints = Checkpoints::new(c.file(config.checkpoint_every, fingerprint));
    if c.resume {
        checkpoints.resume_from_file().map(Some)
    } else {
        Ok(Some(checkpoints))
    }
}

/// Stage 1 in `dir`: trained (its checkpoint saved there), or continued from the checkpoint
/// `from_geometry` (a file, or a run directory holding one) of the same scene and stage-1
/// settings; with the journal the run goes on with (keeping `checkpoints`).
pub(super) fn shared_geometry<'o>(
    config: &GaussianConfig,
    setup: &Setup,
    dir: &mut RunDir,
    device: &Device,
    from_geometry: Option<&Path>,
    observer: &'o dyn Observer,
    checkpoints: Option<Checkpoints<'o>>,
) -> Result<(Journal<'o>, SharedGeometry)> {
    let fingerprint = checkpoint::fingerprint(config, &setup.observed)?;
    if let Some(arg) = from_geometry {
        let c = checkpoint::load(&checkpoint::locate(arg), &fingerprint, device)?;
        let mut journal = Journal::new(RunLog::resume(&dir.file(RunDir::LOG), &c.log)?, observer);
        journal.checkpoints = checkpoints;
        journal.stages.push(c.stage);
        return Ok((journal, c.shared));
    }
    let mut journal = Journal::new(RunLog::create(&dir.file(RunDir::LOG))?, observer);
    journal.checkpoints = checkpoints;
    let shared = train_shared_geometry(config, &setup.observed, device, &mut journal)?;
    let c = Checkpoint {
        shared,
        stage: journal.stages.last().cloned().expect("stage 1 just ran"),
        log: journal.log.saved(),
    };
    // Writing the checkpoint is not training time: it is booked with evaluation.
    let path = dir.file(RunDir::GEOMETRY);
    journal
        .log
        .evaluating(|| checkpoint::save(&path, &c, &fingerprint))?;
    Ok((journal, c.shared))
}

/// R²-Gaussian: every observed channel trained independently; its model saved as
/// `gaussians-<label>`.
fn r2gs(
    config: &GaussianConfig,
    setup: &Setup,
    dir: &mut RunDir,
    device: &Device,
    journal: &mut Journal,
) -> Result<(Volumes, Vec<(GaussianModel, World)>)> {
    let scene = &*setup.observed;
    let geometry = &scene.geometry;
    let mut out = Vec::new();
    let mut models = Vec::new();
    for (c, ch) in scene.channels.iter().enumerate() {
        let views = &setup.views[c];
        let proj = scene.channel_projections(c);
        let (mut model, world) = initial_model(config, geometry, proj, views, device)
            .map_err(|e| e.under(&format!("channels[{c}]")))?;
        let images = views.iter().map(|&v| image(proj, v)).collect();
        let sup = Supervision::single(geometry, &world, views, images, device);
        let eval = scene.references.as_ref().map(|r| Evaluator {
            grid: geometry.volume.clone(),
            world,
            references: vec![r.index_axis(Axis(0), c).to_owned()],
        });
        let stage = Stage::geometry(config, "r2gs", &ch.label, &geometry.volume, &world);
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

/// The spectral stage on the shared geometry; saves the model and returns the observed
/// channels' volumes and, for held-out channels, the predicted ones.
pub(super) fn spectral(
    config: &GaussianConfig,
    setup: &Setup,
    shared: SharedGeometry,
    dir: &mut RunDir,
    device: &Device,
    journal: &mut Journal,
    eval: &Evaluation,
) -> Result<(Volumes, Option<Volumes>, Spectral)> {
    let scene = &*setup.observed;
    let m = scene.n_channels();
    let s = train_spectral(config, scene, shared, device, journal)?;
    let info = ModelInfo::new(
        setup.full,
        scene,
        &(0..m).collect::<Vec<_>>(),
        config.projection,
    );
    let raw_host = crate::gaussian::host_values(&s.raw);
    save_model(
        &dir.file(RunDir::MODEL),
        &s.model,
        Some(raw_host.clone()),
        &s.world,
        &info,
    )?;
    write_ply(
        &dir.file("gaussians.ply"),
        &s.model,
        Some(raw_host),
        &s.world,
        &info.channels,
    )?;
    if let Some(head) = &s.basis {
        crate::query::basis::save_basis(&dir.file(crate::query::BASIS_FILE), head, &s.model)?;
    }
    let v = volumes_with(&s.model, s.raw.clone(), &scene.geometry.volume, &s.world)?;
    let observed = (0..m)
        .map(|c| v.index_axis(Axis(0), c).to_owned())
        .collect();
    if setup.held.is_empty() {
        return Ok((observed, None, s));
    }
    let hold = Holdout {
        model: &s.model,
        raw: &s.raw,
        world: &s.world,
        info: &info,
    };
    let (predicted, scores) = predict_holdout(&hold, setup.full, &setup.held, eval)?;
    dir.write_json(RunDir::HOLDOUT, &scores)?;
    for s in &scores {
        let db = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.2} dB"));
        journal.observer.note(
            Level::Info,
            &format!(
                "held out {:>10}  volume PSNR {}  projection PSNR {} ({} views)",
                s.label,
                db(s.volume.as_ref().map(|v| v.psnr)),
                db(s.proj_psnr),
                s.views
            ),
        );
    }
    Ok((observed, Some(predicted), s))
}

/// Write `train.json` and every channel's volume (observed ones fitted, held-out ones
/// predicted); the scores of the observed channels (held-out ones are in `holdout.json`).
pub(super) fn finish(
    config: &GaussianConfig,
    setup: &Setup,
    dir: &mut RunDir,
    journal: &mut Journal,
    out: Outputs,
    eval: &Evaluation,
) -> Result<Option<Metrics>> {
    let train_s = journal.log.train_s();
    let summary = TrainSummary {
        method: config.method.name(),
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
    let options = config.projection.options();
    let geometry = &setup.observed.geometry;
    let render = |c: usize, views: &[usize]| out.trained.render(geometry, &options, c, views);
    metrics(
        &setup.observed,
        &Reconstruction {
            method: config.method.name(),
            volumes: &fitted,
            views: &setup.views,
            wall_s: train_s,
            unseen: setup.unseen,
            projector: TestProjector::Render {
                what: format!(
                    "the Gaussian renderer ({} projection) from the trained model",
                    config.projection.mode.name()
                ),
                render: &render,
            },
        },
        eval,
    )
}
