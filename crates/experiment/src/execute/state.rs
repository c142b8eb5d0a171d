//! What a cell is made from and whether its directory holds that result: `cell.json`
//! ([`CellRecord`]), compared with what the cell would be made from now ([`run_state`],
//! [`scene_state`]).

use super::{ExecOptions, Execution};
use crate::plan::{CellKind, Plan};
use crate::suite::EvaluationSpec;
use crate::{Error, Result};
use prism_recon::MethodConfig;
use prism_recon::evaluate::Evaluation;
use prism_recon::record::RunDir;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// `cell.json`: what a run cell was made from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellRecord {
    pub cell: String,
    /// The scene config's text and overrides.
    pub scene_config: String,
    pub scene_overrides: Vec<String>,
    /// The method config after overrides and defaults (`config.resolved.yaml`).
    pub method_config: String,
    pub evaluation: EvaluationSpec,
    /// How it ran (informational: a rerun with other `--jobs` does not redo it). Absent in
    /// cells written before it was recorded.
    #[serde(default)]
    pub execution: Option<Execution>,
}

pub const CELL_RECORD: &str = "cell.json";

/// Whether a cell's directory holds its result.
#[derive(Clone, Debug, PartialEq)]
pub enum CellState {
    Done,
    Missing,
    /// Finished under other evaluation settings: its volumes are scored again (no retraining).
    Rescore,
    /// Made from other inputs: what differs.
    Changed(String),
}

pub(super) fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::io(path, e))
}

/// The state of scene cell `i` in `out`.
pub fn scene_state(plan: &Plan, out: &Path, i: usize) -> Result<CellState> {
    let dir = plan.scene_dir(out, i);
    let file = dir.join("scene.yaml");
    if !file.exists() {
        return Ok(CellState::Missing);
    }
    let cell = &plan.scenes[i];
    let yaml: serde_yaml_ng::Value = serde_yaml_ng::from_str(&read_text(&file)?)
        .map_err(|e| prism_domain::yaml::error(&file, &e))?;
    let prov = &yaml["provenance"];
    let recorded: Vec<String> = prov["overrides"]
        .as_sequence()
        .map(|s| {
            s.iter()
                .filter_map(|v| v.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    if prov["config"].as_str() != Some(read_text(&cell.config)?.as_str()) {
        return Ok(CellState::Changed(format!(
            "{} changed since the scene was made",
            cell.config.display()
        )));
    }
    if recorded != cell.overrides.texts() {
        return Ok(CellState::Changed(format!(
            "simulated with overrides {recorded:?}, the suite now gives {:?}",
            cell.overrides.texts()
        )));
    }
    Ok(CellState::Done)
}

/// What run cell `i` is made from now.
pub fn cell_record(plan: &Plan, i: usize, options: &ExecOptions) -> Result<CellRecord> {
    let cell = &plan.runs[i];
    let scene = plan.scene_of(i);
    let mut config = MethodConfig::load_with(&cell.config, &cell.overrides)?;
    if let Some(d) = options.device {
        config.set_device(d);
    }
    Ok(CellRecord {
        cell: cell.key.clone(),
        scene_config: read_text(&scene.config)?,
        scene_overrides: scene.overrides.texts(),
        method_config: config.resolved_yaml()?,
        evaluation: cell_evaluation(plan, i, options).0,
        execution: Some(options.execution()),
    })
}

/// The evaluation run cell `i` is scored under: the suite's, with its scene's object mask.
pub fn cell_evaluation(
    plan: &Plan,
    i: usize,
    options: &ExecOptions,
) -> (EvaluationSpec, Evaluation) {
    let roi = plan.scene_of(i).roi.clone();
    let mut spec = options.evaluation_spec.clone();
    spec.roi = roi.clone();
    let mut eval = options.evaluation.clone();
    eval.protocol.roi = roi;
    (spec, eval)
}

/// The record of a finished run cell's directory, if it has a readable one.
pub fn read_record(dir: &Path) -> Option<CellRecord> {
    let text = std::fs::read_to_string(dir.join(CELL_RECORD)).ok()?;
    serde_json::from_str(&text).ok()
}

/// The state of run cell `i` in `out`.
pub fn run_state(plan: &Plan, out: &Path, i: usize, options: &ExecOptions) -> Result<CellState> {
    let dir = plan.run_dir(out, i);
    if !dir.join(RunDir::MANIFEST).exists() {
        return Ok(CellState::Missing);
    }
    let path = dir.join(CELL_RECORD);
    if !path.exists() {
        return Ok(CellState::Changed(format!(
            "{} was not written by `prism experiment` (no {CELL_RECORD})",
            dir.display()
        )));
    }
    let recorded: CellRecord = serde_json::from_str(&read_text(&path)?)
        .map_err(|e| Error::field(&path, ".", e.to_string()))?;
    let now = cell_record(plan, i, options)?;
    let what = if recorded.scene_config != now.scene_config
        || recorded.scene_overrides != now.scene_overrides
    {
        "its scene's config or overrides"
    } else if recorded.method_config != now.method_config {
        "the method's resolved config"
    } else if recorded.evaluation != now.evaluation {
        // Only the scoring changed: a finished run is scored again from its volumes.
        if plan.runs[i].kind == CellKind::Run
            && dir.join(RunDir::METRICS).exists()
            && !dir.join(RunDir::HOLDOUT).exists()
        {
            return Ok(CellState::Rescore);
        }
        "the evaluation settings"
    } else {
        return Ok(CellState::Done);
    };
    Ok(CellState::Changed(format!("{what} changed since it ran")))
}
