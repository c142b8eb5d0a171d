//! Image figures: slice montages of every method against the reference (with error maps), and the
//! projections of channels held out of training (reference, prediction, residual) with their
//! per-view projection PSNR.

use super::Context;
use crate::Result;
use crate::figures::charts::{Lines, Panel, Series};
use crate::figures::images::{ColourMap, Grid, Tile};
use crate::figures::plot::save;
use crate::plan::StudyPoint;
use crate::results::RunResult;
use ndarray::{Array2, Array3, Axis, s};
use prism_domain::metrics::quantile;
use prism_domain::metrics::{SsimParams, projection_metrics};
use prism_domain::scene::Scene;
use prism_recon::device::cpu_device;
use prism_recon::methods::fourdsg::query::{BasisModel, Predictor, Query, QueryAt};
use prism_recon::record::RunDir;
use std::path::Path;

fn read_volume(path: &Path) -> Option<Array3<f32>> {
    prism_domain::scene::npy::read_array(path, "volume").ok()
}

/// The channels a montage shows: all of up to three, else the first and the last.
fn shown_channels(n: usize) -> Vec<usize> {
    if n <= 3 {
        (0..n).collect()
    } else {
        vec![0, n - 1]
    }
}

/// The middle axial slice of every method of study `i` on `scene` (first seed), with the
/// reference, and each method's error (method − reference) below.
pub(crate) fn slices(
    ctx: &mut Context,
    i: usize,
    views: usize,
    noise: &str,
    scene: &str,
) -> Result<String> {
    let st = ctx.plan.studies[i].clone();
    let seed = st.spec.seeds[0];
    let points: Vec<&StudyPoint> = st
        .points
        .iter()
        .filter(|p| p.scene == scene && p.views == views && p.noise == noise && p.seed == seed)
        .collect();
    let Some(first) = points.first() else {
        return Ok(String::new());
    };
    let scene_dir = ctx.plan.scene_dir(ctx.out, ctx.plan.runs[first.run].scene);
    if !scene_dir.join("scene.yaml").exists() {
        return Ok(String::new());
    }
    let sc = Scene::load(&scene_dir)?;
    let Some(refs) = &sc.references else {
        return Ok(String::new());
    };
    let nz = refs.shape()[1];
    let z = nz / 2;
    let scale = if refs.shape()[2] <= 128 { 2 } else { 1 };
    let mut rows = Vec::new();
    for c in shown_channels(sc.n_channels()) {
        let label = &sc.channels[c].label;
        let reference = refs.slice(s![c, z, .., ..]).to_owned();
        let hi = quantile(refs.index_axis(Axis(0), c).iter().copied(), 0.999).max(1e-6);
        let grey = ColourMap::Grey { lo: 0.0, hi };
        let mut slices: Vec<Option<Array2<f32>>> = Vec::new();
        for p in &points {
            let file = ctx
                .plan
                .run_dir(ctx.out, p.run)
                .join(RunDir::volume_file(label));
            slices.push(
                read_volume(&file)
                    .filter(|v| v.shape()[0] == nz)
                    .map(|v| v.index_axis(Axis(0), z).to_owned()),
            );
        }
        let errors: Vec<Option<Array2<f32>>> = slices
            .iter()
            .map(|s| s.as_ref().map(|s| s - &reference))
            .collect();
        let emax = quantile(
            errors
                .iter()
                .flatten()
                .flat_map(|e| e.iter().map(|v| v.abs())),
            0.99,
        )
        .max(1e-6);
        let mut tiles = vec![Some(Tile {
            caption: "reference".into(),
            image: reference,
            map: grey,
        })];
        let mut err_tiles = vec![None];
        for ((p, sl), er) in points.iter().zip(slices).zip(errors) {
            let name = ctx.loaded.suite.method_label(&p.method).to_string();
            tiles.push(sl.map(|image| Tile {
                caption: name.clone(),
                image,
                map: grey,
            }));
            err_tiles.push(er.map(|image| Tile {
                caption: format!("{name} − ref."),
                image,
                map: ColourMap::Diverging { max: emax },
            }));
        }
        rows.push((label.clone(), tiles));
        rows.push((format!("{label} error"), err_tiles));
    }
    let scene_label = ctx.loaded.suite.scene_label(scene).to_string();
    let grid = Grid {
        title: format!("{scene_label}: axial slice z = {z} of {nz}, {views} views, noise {noise}"),
        note: "grey 0 (black) to the reference's 99.9th percentile (white); errors blue (−) / red (+) \
               to ± their 99th percentile; y down, x right"
            .into(),
        rows,
        scale,
    };
    let paths =
        grid.save(&ctx.figure_stem(&format!("{}-v{views}-{noise}-{scene}-slices", st.spec.name)))?;
    Ok(ctx.embed(
        paths,
        &format!("{scene_label}: slices and errors of every method"),
    ))
}

/// The held-out channels of a run: reference, predicted and residual projections at up to three
/// test views, and the projection PSNR at every view the channel was simulated at.
pub(crate) fn holdout(ctx: &mut Context, p: &StudyPoint) -> Result<String> {
    let dir = ctx.plan.run_dir(ctx.out, p.run);
    if !dir.join(RunDir::MANIFEST).exists() || !dir.join(RunDir::MODEL).exists() {
        return Ok(String::new());
    }
    let run = RunResult::load(&dir, None)?;
    if run.holdout.is_empty() {
        return Ok(String::new());
    }
    let sc = Scene::load(ctx.plan.scene_dir(ctx.out, ctx.plan.runs[p.run].scene))?;
    let model = RunDir::spectral_model(&dir)?;
    let query = Query::open(&model, &cpu_device())?;
    let basis = BasisModel::open(&model, &cpu_device())?;
    let scene_label = ctx.loaded.suite.scene_label(&p.scene).to_string();
    let mut md = String::new();
    for h in &run.holdout {
        let Some(c) = sc.channels.iter().position(|ch| ch.label == h.label) else {
            continue;
        };
        // As the run predicted it: a monoenergetic channel of a basis run from the materials'
        // attenuation at its energy, else interpolated along the spectral axis.
        let pred = match (&basis, h.predictor) {
            (Some(b), Predictor::Physics) if h.unit == "keV" => b.vmi_projections(h.coordinate)?,
            _ => query.projections(QueryAt::Tau(h.tau), false)?,
        };
        let truth = sc.channel_projections(c);
        let views = sc.views_with_channel(c);
        let shown: Vec<usize> = {
            let test: Vec<usize> = sc
                .test_views()
                .iter()
                .copied()
                .filter(|v| views.contains(v))
                .collect();
            if test.is_empty() { views.clone() } else { test }
        }
        .into_iter()
        .take(3)
        .collect();
        let hi = shown
            .iter()
            .map(|&v| quantile(truth.index_axis(Axis(0), v).iter().copied(), 0.999))
            .fold(1e-6f32, f32::max);
        let residuals: Vec<Array2<f32>> = shown
            .iter()
            .map(|&v| &pred.index_axis(Axis(0), v) - &truth.index_axis(Axis(0), v))
            .collect();
        let rmax = quantile(
            residuals.iter().flat_map(|r| r.iter().map(|x| x.abs())),
            0.99,
        )
        .max(1e-6);
        let grey = ColourMap::Grey { lo: 0.0, hi };
        let rows = shown
            .iter()
            .zip(residuals)
            .map(|(&v, res)| {
                let kind = if sc.test_views().contains(&v) {
                    "test"
                } else {
                    "training"
                };
                (
                    format!("view {v} ({kind})"),
                    vec![
                        Some(Tile {
                            caption: "reference".into(),
                            image: truth.index_axis(Axis(0), v).to_owned(),
                            map: grey,
                        }),
                        Some(Tile {
                            caption: "predicted".into(),
                            image: pred.index_axis(Axis(0), v).to_owned(),
                            map: grey,
                        }),
                        Some(Tile {
                            caption: "residual".into(),
                            image: res,
                            map: ColourMap::Diverging { max: rmax },
                        }),
                    ],
                )
            })
            .collect();
        let det = truth.shape()[1];
        let grid = Grid {
            title: format!(
                "{scene_label}: projections of {} ({}), never trained on",
                h.label,
                ctx.loaded.suite.method_label(&p.method)
            ),
            note: format!(
                "line integrals 0 to {hi:.3}; residual (predicted − reference) ± {rmax:.4}; \
                 detector row 0 at the top"
            ),
            rows,
            scale: if det <= 128 { 2 } else { 1 },
        };
        let stem = format!("{}-{}-{}", p.scene, p.method, h.label);
        let paths = grid.save(&ctx.figure_stem(&format!("holdout-{stem}-projections")))?;
        md.push_str(&ctx.embed(
            paths,
            &format!("{scene_label}: unobserved channel {}", h.label),
        ));
        // Projection PSNR (R²-Gaussian's per-view normalisation) at every view.
        let params = SsimParams::default();
        let mut test = Vec::new();
        let mut train = Vec::new();
        for &v in &views {
            let a = pred.slice(s![v..v + 1, .., ..]);
            let b = truth.slice(s![v..v + 1, .., ..]);
            if let Ok((psnr, _)) = projection_metrics(a, b, &params) {
                if sc.test_views().contains(&v) {
                    test.push((v as f64, psnr));
                } else {
                    train.push((v as f64, psnr));
                }
            }
        }
        let fig = Lines {
            title: format!("{scene_label}: projection PSNR of {} per view", h.label),
            cols: 1,
            panel: (640, 340),
            panels: vec![Panel {
                title: String::new(),
                x_label: "view index".into(),
                y_label: "projection PSNR (dB)".into(),
                series: vec![
                    Series::points("training angles", 0, train),
                    Series::points("test angles", 1, test),
                ],
                ..Panel::default()
            }],
        };
        let paths = save(
            &ctx.figure_stem(&format!("holdout-{stem}-psnr-views")),
            &fig,
        )?;
        md.push_str(&ctx.embed(
            paths,
            &format!(
                "{scene_label}: projection PSNR of {} at every view",
                h.label
            ),
        ));
    }
    Ok(md)
}
