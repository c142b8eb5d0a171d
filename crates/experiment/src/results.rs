//! Finished cells read back: each study point's runs (an ablation cell gives one per variant),
//! and `results.csv` with one row per (study point, variant, channel) plus the channel mean.

use crate::plan::{CellKind, Plan, StudyPoint};
use crate::suite::Suite;
use crate::{Error, Result};
use prism_recon::evaluate::Metrics;
use prism_recon::methods::fourdsg::ablation::AblationReport;
use prism_recon::methods::fourdsg::query::HoldoutScore;
use prism_recon::record::RunDir;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// One finished run directory.
#[derive(Clone, Debug)]
pub struct RunResult {
    pub dir: PathBuf,
    /// The ablation variant (`PRSD-FFFL`, `mlp`, …); None for an ordinary run.
    pub variant: Option<String>,
    pub metrics: Metrics,
    /// Channels held out of training and predicted (`holdout.json`).
    pub holdout: Vec<HoldoutScore>,
}

impl RunResult {
    /// Read a published run directory (`metrics.json`, `holdout.json` when present).
    pub fn load(dir: &Path, variant: Option<String>) -> Result<Self> {
        Ok(RunResult {
            dir: dir.to_path_buf(),
            variant,
            metrics: RunDir::read_json(&dir.join(RunDir::METRICS))?,
            holdout: prism_recon::methods::fourdsg::query::holdout::read_scores(dir)?,
        })
    }
}

/// The runs of a study point: None when its cell has not finished; for an ablation, one per
/// variant in the ablation's order.
pub fn point_runs(plan: &Plan, out: &Path, p: &StudyPoint) -> Result<Option<Vec<RunResult>>> {
    let dir = plan.run_dir(out, p.run);
    if !dir.join(RunDir::MANIFEST).exists() {
        return Ok(None);
    }
    match plan.runs[p.run].kind {
        CellKind::Run => Ok(Some(vec![RunResult::load(&dir, None)?])),
        CellKind::Ablation(_) => {
            let report: AblationReport = RunDir::read_json(&dir.join(RunDir::ABLATION))?;
            report
                .rows
                .iter()
                .map(|r| RunResult::load(&dir.join(&r.variant), Some(r.variant.clone())))
                .collect::<Result<Vec<_>>>()
                .map(Some)
        }
    }
}

/// One line of `results.csv`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Row {
    pub study: String,
    pub scene: String,
    pub scene_label: String,
    pub views: usize,
    pub noise: String,
    pub seed: u64,
    pub method: String,
    pub method_label: String,
    /// Ablation variant (empty for ordinary runs).
    pub variant: String,
    /// A channel label, or `mean` (over the fitted channels).
    pub channel: String,
    /// Predicted without training data (a held-out channel).
    pub held_out: bool,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub psnr_slices: Option<f64>,
    pub ssim_slices: Option<f64>,
    pub lpips: Option<f64>,
    /// Mean projection PSNR / SSIM over the test views.
    pub proj_psnr: Option<f64>,
    pub proj_ssim: Option<f64>,
    /// Reconstruction (training) seconds of the whole run, every channel.
    pub wall_s: f64,
    pub channels: usize,
    pub run_dir: String,
}

/// Every row of every study; and the cells not finished.
pub fn collect(suite: &Suite, plan: &Plan, out: &Path) -> Result<(Vec<Row>, Vec<String>)> {
    let mut rows = Vec::new();
    let mut missing = Vec::new();
    for st in &plan.studies {
        for p in &st.points {
            let Some(runs) = point_runs(plan, out, p)? else {
                let key = plan.runs[p.run].key.clone();
                if !missing.contains(&key) {
                    missing.push(key);
                }
                continue;
            };
            for r in &runs {
                rows.extend(rows_of(suite, &st.spec.name, p, r, out));
            }
        }
    }
    Ok((rows, missing))
}

fn rows_of(suite: &Suite, study: &str, p: &StudyPoint, r: &RunResult, out: &Path) -> Vec<Row> {
    let m = &r.metrics;
    let base = Row {
        study: study.to_string(),
        scene: p.scene.clone(),
        scene_label: suite.scene_label(&p.scene).to_string(),
        views: p.views,
        noise: p.noise.clone(),
        seed: p.seed,
        method: p.method.clone(),
        method_label: suite.method_label(&p.method).to_string(),
        variant: r.variant.clone().unwrap_or_default(),
        channel: String::new(),
        held_out: false,
        psnr: None,
        ssim: None,
        psnr_slices: None,
        ssim_slices: None,
        lpips: None,
        proj_psnr: None,
        proj_ssim: None,
        wall_s: m.wall_s,
        channels: m.channels.len(),
        run_dir: r
            .dir
            .strip_prefix(out)
            .unwrap_or(&r.dir)
            .display()
            .to_string(),
    };
    let mut rows: Vec<Row> = m
        .channels
        .iter()
        .map(|c| Row {
            channel: c.label.clone(),
            psnr: Some(c.scores.psnr),
            ssim: Some(c.scores.ssim),
            psnr_slices: Some(c.scores.psnr_slices),
            ssim_slices: Some(c.scores.ssim_slices),
            lpips: c.scores.lpips,
            proj_psnr: c.proj_psnr,
            proj_ssim: c.proj_ssim,
            ..base.clone()
        })
        .collect();
    rows.push(Row {
        channel: "mean".into(),
        psnr: Some(m.mean.psnr),
        ssim: Some(m.mean.ssim),
        psnr_slices: Some(m.mean.psnr_slices),
        ssim_slices: Some(m.mean.ssim_slices),
        lpips: m.mean.lpips,
        ..base.clone()
    });
    rows.extend(r.holdout.iter().map(|h| Row {
        channel: h.label.clone(),
        held_out: true,
        psnr: h.volume.as_ref().map(|v| v.psnr),
        ssim: h.volume.as_ref().map(|v| v.ssim),
        psnr_slices: h.volume.as_ref().map(|v| v.psnr_slices),
        ssim_slices: h.volume.as_ref().map(|v| v.ssim_slices),
        lpips: h.volume.as_ref().and_then(|v| v.lpips),
        proj_psnr: h.proj_psnr,
        proj_ssim: h.proj_ssim,
        ..base.clone()
    }));
    rows
}

/// Write `rows` as CSV (a header, empty fields for absent values).
pub fn write_csv(path: &Path, rows: &[Row]) -> Result<()> {
    let mut w = csv::Writer::from_path(path).map_err(|e| Error::field(path, ".", e.to_string()))?;
    for r in rows {
        w.serialize(r)
            .map_err(|e| Error::field(path, ".", e.to_string()))?;
    }
    w.flush().map_err(|e| Error::io(path, e))
}
