//! `prism recon` for the Gaussian methods: `r2gs` (R²-Gaussian per channel) and `4dsg-stage1`
//! (shared geometry from the structural projections, then per-channel densities on it).
//!
//! A run directory receives, besides the classic outputs (`<label>.npy` in mm⁻¹,
//! `config.resolved.yaml`, `metrics.json`): `log.jsonl` (error vs time, see [`super::log`]),
//! `train.json` (per-stage timing split into render / loss / backward / optimiser / densify),
//! and the models (`gaussians[-<label>].safetensors` + `.ply`, see [`super::io`]).

use super::config::{GaussianConfig, GaussianMethod, StructuralSource};
use super::host::{inverse_softplus, softplus};
use super::init::{density_scale, from_fdk};
use super::io::{save_model, write_ply};
use super::log::RunLog;
use super::model::{GaussianModel, Learnable};
use super::trainer::{
    Evaluator, Stage, StageReport, Supervision, View, target_tensor, train, volumes,
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
use burn::tensor::{Device, Int, Tensor, TensorData};
use indicatif::{ProgressBar, ProgressStyle};
use ndarray::{Array3, ArrayView3, Axis, s};
use serde::Serialize;
use std::fs;
use std::path::Path;

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
    config.validate()?;
    scene.validate()?;
    let unseen = warn_fov(scene)?;
    let views = channel_training_views(scene)?;
    fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    write_resolved(out_dir, config)?;
    let mut log = RunLog::create(out_dir)?;
    let bar = progress_bar();
    let mut stages = Vec::new();
    let vols = match config.method {
        GaussianMethod::R2gs => r2gs(
            config,
            scene,
            &views,
            out_dir,
            device,
            &mut log,
            &bar,
            &mut stages,
        )?,
        GaussianMethod::Stage1 => stage1(
            config,
            scene,
            &views,
            out_dir,
            device,
            &mut log,
            &bar,
            &mut stages,
        )?,
    };
    bar.finish_and_clear();
    let wall_s = log.wall_s();
    let summary = TrainSummary {
        method: config.method.name(),
        scene: &scene.name,
        wall_s,
        train_s: log.train_s(),
        stages: &stages,
    };
    let path = out_dir.join(TRAIN_FILE);
    let json = serde_json::to_string_pretty(&summary)
        .map_err(|e| Error::field(&path, ".", e.to_string()))?;
    fs::write(&path, json + "\n").map_err(|e| Error::io(&path, e))?;
    for (c, ch) in scene.channels.iter().enumerate() {
        write_volume(out_dir, &ch.label, &vols[c])?;
    }
    write_metrics(
        scene,
        &vols,
        config.method.name(),
        log.train_s(),
        unseen,
        out_dir,
    )
}

fn progress_bar() -> ProgressBar {
    let b = ProgressBar::new(0);
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:25}] {pos}/{len} {elapsed_precise} ETA {eta}")
    {
        b.set_style(style.progress_chars("=> "));
    }
    b
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

#[allow(clippy::too_many_arguments)]
fn r2gs(
    config: &GaussianConfig,
    scene: &Scene,
    views: &[Vec<usize>],
    out_dir: &Path,
    device: &Device,
    log: &mut RunLog,
    bar: &ProgressBar,
    stages: &mut Vec<StageReport>,
) -> Result<Vec<Array3<f32>>> {
    let geometry = &scene.geometry;
    let mut out = Vec::new();
    for (c, ch) in scene.channels.iter().enumerate() {
        let proj = scene.channel_projections(c);
        let init_fdk = fdk_of(geometry, proj, &views[c])?;
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
        )
        .map_err(|e| e.under(&format!("channels[{c}]")))?;
        let mut model = GaussianModel::new(&host, bounds, device);
        let images = views[c].iter().map(|&v| image(proj, v)).collect();
        let sup = supervision(
            geometry,
            &world,
            &views[c],
            images,
            vec![None; views[c].len()],
            1,
            device,
        );
        let eval = scene.references.as_ref().map(|r| Evaluator {
            grid: geometry.volume.clone(),
            world,
            references: vec![r.index_axis(Axis(0), c).to_owned()],
        });
        let stage = Stage {
            name: "r2gs",
            channel: &ch.label,
            iterations: config.iterations,
            learn: Learnable::ALL,
            lr: &config.lr,
            loss: &config.loss,
            densify: config.densify.as_ref(),
            eval_every: config.eval_every,
            grid: &geometry.volume,
            world: &world,
            seed: config.seed,
        };
        stages.push(train(&mut model, &sup, eval.as_ref(), &stage, log, bar)?);
        let stem = format!("gaussians-{}", file_stem(&ch.label));
        save_model(
            &out_dir.join(format!("{stem}.safetensors")),
            &model,
            &world,
            std::slice::from_ref(&ch.label),
        )?;
        write_ply(
            &out_dir.join(format!("{stem}.ply")),
            &model,
            &world,
            std::slice::from_ref(&ch.label),
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

#[allow(clippy::too_many_arguments)]
fn stage1(
    config: &GaussianConfig,
    scene: &Scene,
    views: &[Vec<usize>],
    out_dir: &Path,
    device: &Device,
    log: &mut RunLog,
    bar: &ProgressBar,
    stages: &mut Vec<StageReport>,
) -> Result<Vec<Array3<f32>>> {
    let geometry = &scene.geometry;
    let m = scene.n_channels();
    // Geometry stage on the structural projection.
    let (sviews, simages) = structural(config, scene)?;
    let mut stack = ndarray::Array3::<f32>::zeros((
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
    let init_fdk = fdk_of(geometry, stack.view(), &sviews)?;
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
    let mut model = GaussianModel::new(&host, bounds, device);
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
    let stage = Stage {
        name: "geometry",
        channel: "structural",
        iterations: config.iterations,
        learn: Learnable::ALL,
        lr: &config.lr,
        loss: &config.loss,
        densify: config.densify.as_ref(),
        eval_every: config.eval_every,
        grid: &geometry.volume,
        world: &world,
        seed: config.seed,
    };
    stages.push(train(&mut model, &sup, eval.as_ref(), &stage, log, bar)?);

    // Per-channel densities on the fixed geometry, initialised from the common density scaled by
    // each channel's mean line integral relative to the structural one.
    let ratios = channel_ratios(scene, &sviews);
    let common: Vec<f32> = model.to_host().densities;
    let raw: Vec<f32> = common
        .iter()
        .flat_map(|&u| {
            let a = softplus(u as f64);
            ratios.iter().map(move |r| inverse_softplus(a * r) as f32)
        })
        .collect();
    model.set_densities(super::init::tensor2(raw, m, device));
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
    debug_assert!(views.iter().all(|v| !v.is_empty()));
    let sup = supervision(geometry, &world, &all_views, images, columns, m, device);
    let eval = scene.references.as_ref().map(|r| Evaluator {
        grid: geometry.volume.clone(),
        world,
        references: (0..m)
            .map(|c| r.index_axis(Axis(0), c).to_owned())
            .collect(),
    });
    let stage = Stage {
        name: "densities",
        channel: "all",
        iterations: config.density_iterations,
        learn: Learnable::DENSITY,
        lr: &config.lr,
        loss: &config.loss,
        densify: None,
        eval_every: config.eval_every,
        grid: &geometry.volume,
        world: &world,
        seed: config.seed.wrapping_add(1),
    };
    stages.push(train(&mut model, &sup, eval.as_ref(), &stage, log, bar)?);
    let labels: Vec<String> = scene.channels.iter().map(|c| c.label.clone()).collect();
    save_model(
        &out_dir.join("gaussians.safetensors"),
        &model,
        &world,
        &labels,
    )?;
    write_ply(&out_dir.join("gaussians.ply"), &model, &world, &labels)?;
    let v = volumes(&model, &geometry.volume, &world)?;
    Ok((0..m)
        .map(|c| v.index_axis(Axis(0), c).to_owned())
        .collect())
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
