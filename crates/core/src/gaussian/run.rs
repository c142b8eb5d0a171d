//! `prism recon` for the Gaussian methods: `r2gs` (R²-Gaussian per channel), `4dsg-stage1`
//! (shared geometry from the structural projections, then per-channel densities on it) and
//! `4dsg` (the same geometry, then the curve model's stage 2). Stage 1 ([`geometry_stage`]) and
//! the spectral stage ([`spectral_stage`]) are separate steps, so [`super::ablation`] can train
//! several stage-2 variants from one geometry.
//!
//! A run directory receives, besides the classic outputs (`<label>.npy` in mm⁻¹,
//! `config.resolved.yaml`, `metrics.json`): `log.jsonl` (error vs time, see [`super::log`]),
//! `train.json` (per-stage timing split into render / loss / backward / optimiser / densify),
//! and the models (`gaussians[-<label>].safetensors` + `.ply`, see [`super::io`]); `4dsg` and
//! `4dsg-stage1` also leave stage 1's checkpoint (`geometry.safetensors`, see
//! [`super::checkpoint`]), from which [`run_from`] can continue.

use super::checkpoint::{self, Checkpoint, Fingerprint, GEOMETRY_FILE};
use super::config::{GaussianConfig, GaussianMethod, StructuralSource};
use super::host::{inverse_softplus, softplus};
use super::init::{density_scale, from_fdk};
use super::io::{ModelInfo, save_model, write_ply};
use super::log::RunLog;
use super::model::{GaussianModel, Learnable};
use super::query::{Holdout, score_holdout};
use super::trainer::{
    CurveFit, Evaluator, Stage, StageReport, Supervision, View, target_tensor, train, volumes,
    volumes_with,
};
use super::world::World;
use crate::classic::recon::{
    ReconReport, channel_training_views, file_stem, warn_fov, write_metrics, write_resolved,
    write_volume,
};
use crate::classic::{Window, fdk};
use crate::geometry::Geometry;
use crate::scene::Scene;
use crate::{Error, Result};
use burn::optim::AdamConfig;
use burn::tensor::{Device, Int, Tensor, TensorData};
use indicatif::ProgressBar;
use ndarray::{Array3, ArrayView3, Axis, s};
use prism_gscnet::SpectralGrid;
use serde::Serialize;
use std::fs;
use std::path::{Path, PathBuf};

/// Name of the per-stage summary in a run directory.
pub const TRAIN_FILE: &str = "train.json";

#[derive(Serialize)]
struct TrainSummary<'a> {
    method: &'a str,
    scene: &'a str,
    wall_s: f64,
    train_s: f64,
    stages: &'a [StageReport],
}

/// Run a Gaussian method on `scene` into `out_dir` on `device` (a plain CPU or GPU device; the
/// autodiff wrapper is added inside). Returns the metrics report when the scene has references.
pub fn run(
    config: &GaussianConfig,
    scene: &Scene,
    out_dir: &Path,
    device: &Device,
) -> Result<Option<ReconReport>> {
    run_from(config, scene, out_dir, device, None)
}

/// [`run`], for `4dsg` and `4dsg-stage1` optionally continuing from a stage-1 checkpoint
/// ([`super::checkpoint`]: a file, or a run directory holding one) instead of training stage 1.
/// Without one, stage 1 writes its checkpoint into `out_dir`.
pub fn run_from(
    config: &GaussianConfig,
    scene: &Scene,
    out_dir: &Path,
    device: &Device,
    from_geometry: Option<&Path>,
) -> Result<Option<ReconReport>> {
    let setup = Setup::new(config, scene)?;
    if from_geometry.is_some() && config.method == GaussianMethod::R2gs {
        return Err(Error::invalid(
            "method",
            "`r2gs` has no shared geometry: --from-geometry needs `4dsg` or `4dsg-stage1`",
        ));
    }
    let (mut out, shared) = match config.method {
        GaussianMethod::R2gs => (Output::create(out_dir, config, None)?, None),
        GaussianMethod::Stage1 | GaussianMethod::FourDsg => {
            let (out, shared) = shared_geometry(&setup, config, out_dir, device, from_geometry)?;
            (out, Some(shared))
        }
    };
    let mut ctx = setup.ctx(config, &mut out, device);
    let (observed, predicted) = match shared {
        None => (r2gs(&mut ctx)?, None),
        Some(shared) => spectral_stage(&mut ctx, shared)?,
    };
    out.finish(config, &setup, observed, predicted)
}

/// The run directory `dir` with stage 1 done: trained there (its checkpoint saved with it), or
/// continued from the checkpoint `from_geometry` (a file, or a run directory holding one) of the
/// same scene and stage-1 settings. The checkpoint is read before `dir` is created, so a refused
/// one leaves nothing behind and one inside `dir` is not overwritten first.
pub(super) fn shared_geometry(
    setup: &Setup,
    config: &GaussianConfig,
    dir: &Path,
    device: &Device,
    from_geometry: Option<&Path>,
) -> Result<(Output, SharedGeometry)> {
    let fingerprint = Fingerprint::new(config, &setup.observed)?;
    if let Some(arg) = from_geometry {
        let c = checkpoint::load(&checkpoint::locate(arg), &fingerprint, device)?;
        return Ok((Output::resume(dir, config, &c)?, c.shared));
    }
    let mut out = Output::create(dir, config, None)?;
    let mut ctx = setup.ctx(config, &mut out, device);
    let shared = geometry_stage(&mut ctx)?;
    ctx.save_geometry(&shared, &fingerprint)?;
    Ok((out, shared))
}

/// One volume per channel (mm⁻¹, `[z][y][x]`).
pub(super) type Volumes = Vec<Array3<f32>>;

/// The scene as training sees it: held-out channels removed, training views per channel.
pub(super) struct Setup<'a> {
    /// The full scene (held-out channels included, for scoring predictions).
    pub full: &'a Scene,
    /// The scene without held-out channels.
    pub observed: Scene,
    /// Indices (in `full`) of the held-out channels.
    pub held: Vec<usize>,
    /// Training views of each observed channel.
    pub views: Vec<Vec<usize>>,
    /// Fraction of the volume outside the field of view (for the metrics' note).
    pub unseen: f64,
}

impl<'a> Setup<'a> {
    pub fn new(config: &GaussianConfig, scene: &'a Scene) -> Result<Self> {
        config.validate()?;
        scene.validate()?;
        let unseen = warn_fov(scene)?;
        let held = config.holdout_indices(scene)?;
        let observed = scene_without(scene, &held);
        let views = channel_training_views(&observed)?;
        Ok(Setup {
            full: scene,
            observed,
            held,
            views,
            unseen,
        })
    }

    pub fn ctx<'c>(
        &'c self,
        config: &'c GaussianConfig,
        out: &'c mut Output,
        device: &'c Device,
    ) -> Ctx<'c> {
        Ctx {
            config,
            scene: &self.observed,
            full: self.full,
            held: &self.held,
            views: &self.views,
            device,
            out,
        }
    }
}

/// A run directory being filled: its log, progress bar and stage summaries.
pub(super) struct Output {
    pub dir: PathBuf,
    pub log: RunLog,
    pub bar: ProgressBar,
    pub stages: Vec<StageReport>,
}

impl Output {
    /// Create `dir` with `config.resolved.yaml` and a log; with `parent`, the log and the stage
    /// summaries continue the parent's (a variant that reuses the parent's stage 1).
    pub fn create(dir: &Path, config: &GaussianConfig, parent: Option<&Output>) -> Result<Self> {
        fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        write_resolved(dir, config)?;
        let (log, stages) = match parent {
            Some(p) => (p.log.fork(dir)?, p.stages.clone()),
            None => (RunLog::create(dir)?, Vec::new()),
        };
        Ok(Output {
            dir: dir.to_path_buf(),
            log,
            bar: progress_bar(),
            stages,
        })
    }

    /// Create `dir` continuing a stage-1 checkpoint's log and summary.
    fn resume(dir: &Path, config: &GaussianConfig, c: &Checkpoint) -> Result<Self> {
        fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        write_resolved(dir, config)?;
        Ok(Output {
            dir: dir.to_path_buf(),
            log: RunLog::resume(dir, &c.log)?,
            bar: progress_bar(),
            stages: vec![c.stage.clone()],
        })
    }

    /// Write `train.json`, every channel's volume (observed ones fitted, held-out ones predicted)
    /// and `metrics.json` for the observed channels (held-out ones are in `holdout.json`).
    pub fn finish(
        self,
        config: &GaussianConfig,
        setup: &Setup,
        observed: Volumes,
        predicted: Option<Volumes>,
    ) -> Result<Option<ReconReport>> {
        self.bar.finish_and_clear();
        let train_s = self.log.train_s();
        let summary = TrainSummary {
            method: config.method.name(),
            scene: &setup.full.name,
            wall_s: self.log.wall_s(),
            train_s,
            stages: &self.stages,
        };
        let path = self.dir.join(TRAIN_FILE);
        let json = serde_json::to_string_pretty(&summary)
            .map_err(|e| Error::field(&path, ".", e.to_string()))?;
        fs::write(&path, json + "\n").map_err(|e| Error::io(&path, e))?;
        let mut next_observed = observed.into_iter();
        let mut next_held = predicted.into_iter().flatten();
        let mut fitted = Vec::new();
        for (c, ch) in setup.full.channels.iter().enumerate() {
            let held = setup.held.contains(&c);
            let v = if held {
                next_held.next()
            } else {
                next_observed.next()
            }
            .expect("one volume per channel");
            write_volume(&self.dir, &ch.label, &v)?;
            if !held {
                fitted.push(v);
            }
        }
        write_metrics(
            &setup.observed,
            &fitted,
            config.method.name(),
            train_s,
            setup.unseen,
            &self.dir,
        )
    }
}

/// Everything a method runner needs.
pub(super) struct Ctx<'a> {
    config: &'a GaussianConfig,
    /// The scene without held-out channels (what training sees).
    scene: &'a Scene,
    /// The full scene (held-out channels included, for scoring predictions).
    full: &'a Scene,
    /// Held-out channel indices in `full`.
    held: &'a [usize],
    views: &'a [Vec<usize>],
    device: &'a Device,
    out: &'a mut Output,
}

impl Ctx<'_> {
    fn train(
        &mut self,
        model: &mut GaussianModel,
        sup: &Supervision,
        eval: Option<&Evaluator>,
        stage: &Stage,
        curve: Option<&mut CurveFit>,
    ) -> Result<()> {
        let o = &mut *self.out;
        let r = train(model, sup, eval, stage, curve, &mut o.log, &o.bar)?;
        o.stages.push(r);
        Ok(())
    }

    /// Write stage 1's checkpoint ([`super::checkpoint`]) into the run directory. The write is
    /// not training time: it is booked with evaluation.
    fn save_geometry(&mut self, shared: &SharedGeometry, fingerprint: &Fingerprint) -> Result<()> {
        let o = &mut *self.out;
        let c = Checkpoint {
            shared: shared.clone(),
            stage: o.stages.last().cloned().expect("stage 1 just ran"),
            log: o.log.saved(),
        };
        let path = o.dir.join(GEOMETRY_FILE);
        o.log
            .evaluating(|| checkpoint::save(&path, &c, fingerprint))
    }

    fn info(&self, channels: &[usize]) -> ModelInfo {
        let coords: Vec<f64> = self
            .full
            .channels
            .iter()
            .map(|c| c.coordinate.value())
            .collect();
        let lo = coords.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = coords.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        ModelInfo {
            channels: channels
                .iter()
                .map(|&c| self.scene.channels[c].label.clone())
                .collect(),
            tau: channels
                .iter()
                .map(|&c| self.scene.channels[c].tau)
                .collect(),
            coordinates: channels
                .iter()
                .map(|&c| self.scene.channels[c].coordinate.value())
                .collect(),
            unit: self.scene.channels[channels[0]]
                .coordinate
                .unit()
                .to_string(),
            coordinate_range: [lo, hi],
            geometry: self.scene.geometry.clone(),
            projection: self.config.projection,
        }
    }
}

/// A geometry stage with the config's settings.
fn base_stage<'s>(
    c: &'s GaussianConfig,
    scene: &'s Scene,
    name: &'s str,
    channel: &'s str,
    world: &'s World,
) -> Stage<'s> {
    Stage {
        name,
        channel,
        iterations: c.iterations,
        learn: Learnable::ALL,
        lr: &c.lr,
        loss: &c.loss,
        projection: c.projection.options(),
        densify: c.densify.as_ref(),
        eval_every: c.eval_every,
        grid: &scene.geometry.volume,
        world,
        seed: c.seed,
    }
}

/// `scene` without the listed channels (τ kept as in the full scene).
fn scene_without(scene: &Scene, held: &[usize]) -> Scene {
    if held.is_empty() {
        return scene.clone();
    }
    let keep: Vec<usize> = (0..scene.n_channels())
        .filter(|c| !held.contains(c))
        .collect();
    Scene {
        channels: keep.iter().map(|&c| scene.channels[c].clone()).collect(),
        projections: scene.projections.select(Axis(0), &keep),
        availability: scene.availability.select(Axis(1), &keep),
        references: scene.references.as_ref().map(|r| r.select(Axis(0), &keep)),
        ..scene.clone()
    }
}

fn progress_bar() -> ProgressBar {
    crate::progress::bar(
        0,
        "{msg} [{bar:25}] {pos}/{len} {elapsed_precise} ETA {eta}",
    )
}

/// FDK (ram-lak) of `projections` (`[view][row][col]` for the listed views of `geometry`).
fn fdk_of(
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    views: &[usize],
) -> Result<Array3<f32>> {
    let sub = Geometry {
        angles_rad: views.iter().map(|&v| geometry.angles_rad[v]).collect(),
        ..geometry.clone()
    };
    fdk(
        &sub,
        projections.select(Axis(0), views).view(),
        Window::RamLak,
    )
}

/// Training views with one image per listed view: `images[i]` is `[n][rows][cols]` (measured
/// line integrals) of view `views[i]`, `columns[i]` the supervised density columns (None: all).
fn supervision(
    geometry: &Geometry,
    world: &World,
    views: &[usize],
    images: Vec<Vec<f32>>,
    columns: Vec<Option<Vec<usize>>>,
    total_columns: usize,
    device: &Device,
) -> Supervision {
    let g = world.geometry(geometry);
    let (rows, cols) = (geometry.detector.rows, geometry.detector.cols);
    let f = world.projection_factor() as f32;
    let views = views
        .iter()
        .zip(images)
        .zip(columns)
        .map(|((&v, img), c)| {
            let n = img.len() / (rows * cols);
            View {
                camera: g.camera(v),
                target: target_tensor(img.iter().map(|x| x * f).collect(), n, rows, cols, device),
                columns: c.map(|c| {
                    let idx: Vec<i64> = c.iter().map(|&i| i as i64).collect();
                    Tensor::<1, Int>::from_data(TensorData::new(idx, [c.len()]), device)
                }),
            }
        })
        .collect();
    Supervision {
        views,
        columns: total_columns,
    }
}

fn image(p: ArrayView3<f32>, v: usize) -> Vec<f32> {
    p.index_axis(Axis(0), v).iter().copied().collect()
}

/// The initial model and its world from an FDK of `projections` at `views`.
fn initial_model(
    config: &GaussianConfig,
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    views: &[usize],
    device: &Device,
) -> Result<(GaussianModel, World)> {
    let init_fdk = fdk_of(geometry, projections, views)?;
    let world = World::new(geometry, density_scale(init_fdk.view())?)?;
    let bounds = config.bounds();
    let host = from_fdk(
        init_fdk.view(),
        &geometry.volume,
        &world,
        &bounds,
        &config.init,
        config.seed,
        device,
    )?;
    Ok((GaussianModel::new(&host, bounds, device), world))
}

fn r2gs(ctx: &mut Ctx) -> Result<Vec<Array3<f32>>> {
    let (config, scene, device) = (ctx.config, ctx.scene, ctx.device);
    let geometry = &scene.geometry;
    let mut out = Vec::new();
    for (c, ch) in scene.channels.iter().enumerate() {
        let views = &ctx.views[c];
        let proj = scene.channel_projections(c);
        let (mut model, world) = initial_model(config, geometry, proj, views, device)
            .map_err(|e| e.under(&format!("channels[{c}]")))?;
        let images = views.iter().map(|&v| image(proj, v)).collect();
        let sup = supervision(
            geometry,
            &world,
            views,
            images,
            vec![None; views.len()],
            1,
            device,
        );
        let eval = scene.references.as_ref().map(|r| Evaluator {
            grid: geometry.volume.clone(),
            world,
            references: vec![r.index_axis(Axis(0), c).to_owned()],
        });
        let stage = base_stage(config, scene, "r2gs", &ch.label, &world);
        ctx.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
        let stem = format!("gaussians-{}", file_stem(&ch.label));
        let info = ctx.info(&[c]);
        save_model(
            &ctx.out.dir.join(format!("{stem}.safetensors")),
            &model,
            None,
            &world,
            &info,
        )?;
        write_ply(
            &ctx.out.dir.join(format!("{stem}.ply")),
            &model,
            None,
            &world,
            &info.channels,
        )?;
        let v = volumes(&model, &geometry.volume, &world)?;
        out.push(v.index_axis(Axis(0), 0).to_owned());
    }
    Ok(out)
}

/// The structural projections of 4D-SG stage 1: `(views, images)`.
fn structural(config: &GaussianConfig, scene: &Scene) -> Result<(Vec<usize>, Vec<Vec<f32>>)> {
    let provided = scene.structural.as_ref();
    match (config.structural, provided) {
        (StructuralSource::Provided, None) => Err(Error::invalid(
            "structural",
            "`provided` needs a scene with a measured full-spectrum projection",
        )),
        (StructuralSource::Provided | StructuralSource::Auto, Some(p)) => {
            let views = scene.train_views().to_vec();
            let images = views.iter().map(|&v| image(p.view(), v)).collect();
            Ok((views, images))
        }
        _ => {
            let m = scene.n_channels();
            let views: Vec<usize> = scene
                .train_views()
                .iter()
                .copied()
                .filter(|&v| (0..m).all(|c| scene.availability[[v, c]]))
                .collect();
            if views.is_empty() {
                return Err(Error::invalid(
                    "availability",
                    "no training view has every channel, so no mean structural projection \
                     exists; provide a measured one (scene `structural`)",
                ));
            }
            let images = views
                .iter()
                .map(|&v| {
                    let mean = scene
                        .projections
                        .slice(s![.., v, .., ..])
                        .mean_axis(Axis(0))
                        .expect("at least one channel");
                    mean.iter().copied().collect()
                })
                .collect();
            Ok((views, images))
        }
    }
}

/// 4D-SG stage 1's result: the shared geometry (with the common raw density) and its world.
#[derive(Clone)]
pub struct SharedGeometry {
    pub model: GaussianModel,
    pub world: World,
    /// The views of the structural projections.
    pub views: Vec<usize>,
}

/// 4D-SG stage 1: the shared geometry and common density from the structural projection.
pub(super) fn geometry_stage(ctx: &mut Ctx) -> Result<SharedGeometry> {
    let (config, scene, device) = (ctx.config, ctx.scene, ctx.device);
    let geometry = &scene.geometry;
    let (sviews, simages) = structural(config, scene)?;
    let mut stack = Array3::<f32>::zeros((
        geometry.views(),
        geometry.detector.rows,
        geometry.detector.cols,
    ));
    for (v, img) in sviews.iter().zip(&simages) {
        stack
            .index_axis_mut(Axis(0), *v)
            .iter_mut()
            .zip(img)
            .for_each(|(a, b)| *a = *b);
    }
    let (mut model, world) = initial_model(config, geometry, stack.view(), &sviews, device)?;
    let sup = supervision(
        geometry,
        &world,
        &sviews,
        simages,
        vec![None; sviews.len()],
        1,
        device,
    );
    let eval = scene.references.as_ref().map(|r| Evaluator {
        grid: geometry.volume.clone(),
        world,
        references: vec![r.mean_axis(Axis(0)).expect("at least one channel")],
    });
    let stage = base_stage(config, scene, "geometry", "structural", &world);
    ctx.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
    Ok(SharedGeometry {
        model,
        world,
        views: sviews,
    })
}

/// 4D-SG on a trained shared geometry: per-channel densities, directly (`4dsg-stage1`) or
/// through the curve model (`4dsg`, stage 2). Saves the model and returns the observed
/// channels' volumes and, for held-out channels, the predicted ones.
pub(super) fn spectral_stage(
    ctx: &mut Ctx,
    shared: SharedGeometry,
) -> Result<(Volumes, Option<Volumes>)> {
    let (config, scene, device) = (ctx.config, ctx.scene, ctx.device);
    let geometry = &scene.geometry;
    let m = scene.n_channels();
    let SharedGeometry {
        mut model,
        world,
        views: sviews,
    } = shared;

    // Stage 2 supervision: every available channel at every training view.
    let all_views: Vec<usize> = scene
        .train_views()
        .iter()
        .copied()
        .filter(|&v| (0..m).any(|c| scene.availability[[v, c]]))
        .collect();
    let mut images = Vec::new();
    let mut columns = Vec::new();
    for &v in &all_views {
        let avail = scene.available_channels(v);
        let mut img = Vec::new();
        for &c in &avail {
            img.extend(image(scene.channel_projections(c), v));
        }
        images.push(img);
        columns.push((avail.len() < m).then_some(avail));
    }
    let sup = supervision(geometry, &world, &all_views, images, columns, m, device);
    let eval = scene.references.as_ref().map(|r| Evaluator {
        grid: geometry.volume.clone(),
        world,
        references: (0..m)
            .map(|c| r.index_axis(Axis(0), c).to_owned())
            .collect(),
    });
    let info = ctx.info(&(0..m).collect::<Vec<_>>());
    let raw = match config.method {
        GaussianMethod::FourDsg if m >= 2 => {
            let s2 = &config.stage2;
            let grid = SpectralGrid::new(info.tau.iter().map(|&t| t as f32).collect())
                .map_err(|e| Error::invalid("channels", e.to_string()))?;
            let ad = device.clone().autodiff();
            let mut net = s2
                .curve_model
                .init(&grid, &ad, config.seed)
                .map_err(|e| Error::invalid("stage2.curve_model", e.to_string()))?;
            let u = sorted_finite(model.to_host().densities);
            let baseline = spectral_baseline(&u, &channel_ratios(scene, &sviews));
            net.set_baseline(&baseline)
                .map_err(|e| Error::invalid("stage2.curve_model", e.to_string()))?;
            if s2.condition_on_stage1 {
                let (lo, mid, hi) = (quantile(&u, 0.1), quantile(&u, 0.5), quantile(&u, 0.9));
                net.set_density_conditioning(mid, ((hi - lo) / 2.0).max(0.1))
                    .map_err(|e| Error::invalid("stage2.curve_model", e.to_string()))?;
            }
            let mut fit = CurveFit {
                net,
                optim: AdamConfig::new().init(),
                tau: grid.to_tensor(&ad),
                lambda_curve: s2.lambda_curve,
                lr: s2.lr_network,
            };
            let stage = Stage {
                iterations: s2.iterations,
                learn: s2.freeze.learnable(),
                densify: None,
                seed: config.seed.wrapping_add(1),
                ..base_stage(config, scene, s2.curve_model.kind.name(), "all", &world)
            };
            ctx.train(&mut model, &sup, eval.as_ref(), &stage, Some(&mut fit))?;
            fit.raw_densities(&model)?
        }
        _ => {
            if config.method == GaussianMethod::FourDsg {
                eprintln!(
                    "note: one observed channel: no spectral axis, stage 2 is skipped and the \
                     stage-1 densities are the result"
                );
            }
            // 4dsg-stage1: per-channel densities fitted directly on the fixed geometry,
            // initialised from the common density scaled by each channel's mean line integral
            // relative to the channels' average.
            let ratios = channel_ratios(scene, &sviews);
            let common: Vec<f32> = model.to_host().densities;
            let raw: Vec<f32> = common
                .iter()
                .flat_map(|&u| {
                    let a = softplus(u as f64);
                    ratios.iter().map(move |r| inverse_softplus(a * r) as f32)
                })
                .collect();
            model.set_densities(super::upload(raw, m, device));
            let stage = Stage {
                iterations: config.density_iterations,
                learn: Learnable::DENSITY,
                densify: None,
                seed: config.seed.wrapping_add(1),
                ..base_stage(config, scene, "densities", "all", &world)
            };
            ctx.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
            model.densities.value.clone()
        }
    };
    let raw_host = super::host_values(&raw);
    save_model(
        &ctx.out.dir.join("gaussians.safetensors"),
        &model,
        Some(raw_host.clone()),
        &world,
        &info,
    )?;
    write_ply(
        &ctx.out.dir.join("gaussians.ply"),
        &model,
        Some(raw_host),
        &world,
        &info.channels,
    )?;
    let v = volumes_with(&model, raw.clone(), &geometry.volume, &world)?;
    let observed = (0..m)
        .map(|c| v.index_axis(Axis(0), c).to_owned())
        .collect();
    let predicted = if ctx.held.is_empty() {
        None
    } else {
        let hold = Holdout {
            model: &model,
            raw: &raw,
            world: &world,
            info: &info,
        };
        Some(score_holdout(&hold, ctx.full, ctx.held, &ctx.out.dir)?)
    };
    Ok((observed, predicted))
}

/// The finite values of `v`, ascending.
fn sorted_finite(mut v: Vec<f32>) -> Vec<f32> {
    v.retain(|x| x.is_finite());
    v.sort_by(f32::total_cmp);
    v
}

/// The `q`-quantile (nearest rank) of ascending `sorted` (0 when empty).
fn quantile(sorted: &[f32], q: f64) -> f32 {
    let i = ((sorted.len().saturating_sub(1)) as f64 * q).round() as usize;
    sorted.get(i).copied().unwrap_or(0.0)
}

/// Raw-density offsets b [M] that turn the structural densities into each channel's, for the
/// curve model's baseline: softplus(ū + b_m) = r_m·softplus(ū) at the median ū of the ascending
/// raw densities `sorted` (`ratios` from [`channel_ratios`]).
fn spectral_baseline(sorted: &[f32], ratios: &[f64]) -> Vec<f32> {
    let u = quantile(sorted, 0.5) as f64;
    let a = softplus(u);
    ratios
        .iter()
        .map(|&r| (inverse_softplus(a * r) - u) as f32)
        .collect()
}

/// Mean line integral of each channel over the structural views, divided by the structural mean.
fn channel_ratios(scene: &Scene, views: &[usize]) -> Vec<f64> {
    let m = scene.n_channels();
    let means: Vec<f64> = (0..m)
        .map(|c| {
            let p = scene.channel_projections(c);
            let (sum, n) = views.iter().fold((0.0f64, 0usize), |(s, n), &v| {
                let img = p.index_axis(Axis(0), v);
                (
                    s + img.iter().map(|&x| x as f64).sum::<f64>(),
                    n + img.len(),
                )
            });
            sum / n.max(1) as f64
        })
        .collect();
    let mean = means.iter().sum::<f64>() / m as f64;
    means
        .iter()
        .map(|&x| if mean > 0.0 && x > 0.0 { x / mean } else { 1.0 })
        .collect()
}
