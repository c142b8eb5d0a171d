//! Stage-2 ablations of 4D-SG from one shared geometry: `prism ablate freeze | curve-model`.
//!
//! Stage 1 runs once; every variant then trains stage 2 from a copy of that geometry into its
//! own complete run directory (`<out>/<variant>/`: volumes, `metrics.json`, `log.jsonl`,
//! `train.json`, the model; `holdout.json` with held-out channels). Variant logs and times
//! include the shared stage 1, so each directory reads like an ordinary `prism recon` run. The
//! table goes to `<out>/ablation.json` and `<out>/ablation.md`.
//!
//! Variants differ only in `stage2` (and the same seed), so differences are the ablated
//! choice's alone.

use super::config::{FourDsgConfig, FourDsgMethod};
use super::run::{shared_geometry, spectral};
use crate::evaluate::Metrics;
use crate::gaussians::finish::{Outputs, finish};
use crate::gaussians::train::Journal;
use crate::methods::fourdsg::stage2::config::Freeze;
use crate::record::RunDir;
use crate::setup::{RunOptions, Setup};
use crate::{Error, Result};
use prism_domain::observe::Level;
use prism_domain::scene::Scene;
use prism_gscnet::CurveModelKind;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::PathBuf;

/// What an ablation varies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Study {
    /// The paper's freezing strategies (`fig:freeze_strategy`): which of position / rotation /
    /// scale / common raw density stay learnable in stage 2.
    Freeze,
    /// GSC-Net against the direct MLP (`fig:gscnet_mlp_view_ablation`).
    CurveModel,
}

/// One stage-2 variant: a directory name and its config.
#[derive(Clone, Debug)]
pub struct Variant {
    pub name: String,
    pub config: FourDsgConfig,
}

impl Study {
    pub fn name(self) -> &'static str {
        match self {
            Study::Freeze => "freeze",
            Study::CurveModel => "curve-model",
        }
    }

    /// The variants of this study around `base` (its other settings kept).
    ///
    /// Freeze: the paper's FFFL (geometry fixed, density learnable), all learnable (our default),
    /// all frozen (only the network learns), each geometric group alone learnable, and the
    /// geometry learnable with the density frozen.
    pub fn variants(self, base: &FourDsgConfig) -> Vec<Variant> {
        match self {
            Study::Freeze => {
                let p = Freeze::PAPER;
                let strategies = [
                    (p.position, p.rotation, p.scale, p.density),
                    (false, false, false, false),
                    (true, true, true, true),
                    (false, true, true, false),
                    (true, false, true, false),
                    (true, true, false, false),
                    (false, false, false, true),
                ];
                strategies
                    .iter()
                    .map(|&(position, rotation, scale, density)| {
                        let mut config = base.clone();
                        config.spectral.stage2.freeze = Freeze {
                            position,
                            rotation,
                            scale,
                            density,
                        };
                        Variant {
                            name: format!("PRSD-{}", config.spectral.stage2.freeze.code()),
                            config,
                        }
                    })
                    .collect()
            }
            Study::CurveModel => [CurveModelKind::Gscnet, CurveModelKind::Mlp]
                .iter()
                .map(|&kind| {
                    let mut config = base.clone();
                    config.spectral.stage2.curve_model.kind = kind;
                    Variant {
                        name: kind.name().to_string(),
                        config,
                    }
                })
                .collect(),
        }
    }
}

/// One row of the ablation table.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AblationRow {
    pub variant: String,
    /// P/R/S/D learnable (L) or frozen (F) in stage 2.
    pub freeze: String,
    pub curve_model: String,
    /// Mean 3-D PSNR (dB) / SSIM over the observed channels (absent without references).
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    /// Per observed channel: `(label, PSNR)`.
    pub channel_psnr: Vec<(String, f64)>,
    /// Seconds of stage 2 alone, and of the whole run (shared stage 1 included).
    pub stage2_s: f64,
    pub train_s: f64,
}

/// Contents of `ablation.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AblationReport {
    pub study: String,
    pub scene: String,
    /// Training seconds of the shared stage 1.
    pub stage1_s: f64,
    pub rows: Vec<AblationRow>,
}

/// Run `study` around `base` (a `4dsg` config) on `scene` into `dir` and publish it: stage 1
/// once into `geometry/` (or continued from `options.from_geometry`), then one complete run
/// directory per variant, `ablation.json` and `ablation.md`.
pub fn ablate(
    base: &FourDsgConfig,
    study: Study,
    scene: &Scene,
    mut dir: RunDir,
    options: &RunOptions,
) -> Result<(PathBuf, AblationReport)> {
    if base.method != FourDsgMethod::Full {
        return Err(Error::invalid(
            "method",
            format!(
                "ablations vary stage 2 of `4dsg`; the config has `{}`",
                base.method.name()
            ),
        ));
    }
    base.validate()?;
    let observer = options.observer;
    let setup = Setup::new(scene, base.holdout_indices(scene)?, options)?;
    if setup.observed.n_channels() < 2 {
        return Err(Error::invalid(
            "channels",
            "a stage-2 ablation needs at least two observed channels (with one, stage 2 is skipped)",
        ));
    }
    // Stage 1 once (or from a checkpoint); its checkpoint goes to `geometry/`.
    let mut geometry = dir.child("geometry")?;
    let resolved = |c: &FourDsgConfig| {
        serde_yaml_ng::to_string(c).map_err(|e| Error::invalid("config", e.to_string()))
    };
    geometry.write_text(RunDir::CONFIG, &resolved(base)?)?;
    let (mut root, shared) = shared_geometry(
        base,
        &setup,
        &mut geometry,
        &options.device,
        options.from_geometry,
        observer,
        None,
    )?;
    root.log.stop();
    geometry.publish()?;
    let stage1_s = root.log.train_s();
    let mut rows = Vec::new();
    for v in study.variants(base) {
        observer.note(
            Level::Info,
            &format!("ablation {}: variant {}", study.name(), v.name),
        );
        let mut vdir = dir.child(&v.name)?;
        vdir.write_text(RunDir::CONFIG, &resolved(&v.config)?)?;
        let mut journal = Journal::new(root.log.fork(&vdir.file(RunDir::LOG))?, observer);
        journal.stages = root.stages.clone();
        let (observed, predicted, s) = spectral(
            &v.config,
            &setup,
            shared.clone(),
            &mut vdir,
            &options.device,
            &mut journal,
            options.evaluation,
        )?;
        let train_s = journal.log.train_s();
        let out = Outputs {
            observed,
            predicted,
            trained: s.trained(),
        };
        let metrics = finish(
            v.config.method.name(),
            &v.config.geometry.projection,
            &setup,
            &mut vdir,
            &mut journal,
            out,
            options.evaluation,
        )?;
        if let Some(m) = &metrics {
            vdir.write_json(RunDir::METRICS, m)?;
        }
        vdir.publish()?;
        rows.push(row(&v, metrics.as_ref(), train_s - stage1_s, train_s));
    }
    let report = AblationReport {
        study: study.name().to_string(),
        scene: scene.name.clone(),
        stage1_s,
        rows,
    };
    dir.write_json(RunDir::ABLATION, &report)?;
    dir.write_text("ablation.md", &markdown(&report))?;
    Ok((dir.publish()?, report))
}

fn row(v: &Variant, report: Option<&Metrics>, stage2_s: f64, train_s: f64) -> AblationRow {
    AblationRow {
        variant: v.name.clone(),
        freeze: v.config.spectral.stage2.freeze.code(),
        curve_model: v.config.spectral.stage2.curve_model.kind.name().to_string(),
        psnr: report.map(|r| r.mean.psnr),
        ssim: report.map(|r| r.mean.ssim),
        channel_psnr: report
            .map(|r| {
                r.channels
                    .iter()
                    .map(|c| (c.label.clone(), c.scores.psnr))
                    .collect()
            })
            .unwrap_or_default(),
        stage2_s,
        train_s,
    }
}

/// The table as Markdown (one row per variant; PSNR in dB, times in seconds).
pub fn markdown(report: &AblationReport) -> String {
    let mut s = format!(
        "# Ablation `{}` on `{}` (shared stage 1: {:.0} s)\n\n",
        report.study, report.scene, report.stage1_s
    );
    let labels: Vec<&str> = report
        .rows
        .first()
        .map(|r| r.channel_psnr.iter().map(|(l, _)| l.as_str()).collect())
        .unwrap_or_default();
    s.push_str("| variant | P R S D | curve model | PSNR | SSIM |");
    for l in &labels {
        let _ = write!(s, " {l} |");
    }
    s.push_str(" stage 2 s | total s |\n|---|---|---|---|---|");
    s.push_str(&"---|".repeat(labels.len() + 2));
    s.push('\n');
    let num = |v: Option<f64>, digits: usize| match v {
        Some(x) => format!("{x:.digits$}"),
        None => "–".to_string(),
    };
    for r in &report.rows {
        let prsd: Vec<String> = r.freeze.chars().map(String::from).collect();
        let _ = write!(
            s,
            "| {} | {} | {} | {} | {} |",
            r.variant,
            prsd.join(" "),
            r.curve_model,
            num(r.psnr, 2),
            num(r.ssim, 4)
        );
        for (_, p) in &r.channel_psnr {
            let _ = write!(s, " {p:.2} |");
        }
        let _ = writeln!(s, " {:.0} | {:.0} |", r.stage2_s, r.train_s);
    }
    s
}
