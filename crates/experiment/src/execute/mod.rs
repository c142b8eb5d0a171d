//! Running a plan's cells: one at a time on every thread, or `jobs` at a time with the threads
//! split between them (each cell on its own rayon pool of `threads / jobs`). Timings are only
//! comparable between cells run the same way, so every cell records how it ran (`cell.json`'s
//! `execution`) and the report states it.
//!
//! Every cell directory is published atomically, so a directory that exists is finished. Each
//! carries what it was made from (a scene's provenance: its config text and overrides; a run's
//! `cell.json`: its scene's, the resolved method config and the evaluation), so a rerun skips
//! finished cells, and refuses (or with `force`, redoes) cells whose inputs changed since; a run
//! whose only change is the evaluation is scored again from its volumes. A cell that fails is
//! recorded and the others go on.

use crate::plan::{CellKind, Plan, SCENES};
use crate::suite::EvaluationSpec;
use crate::{Error, Result};
use prism_domain::import::{self, ImportConfig};
use prism_domain::observe::{Level, Observer};
use prism_domain::scene::Scene;
use prism_domain::simulate::{SimulateConfig, simulate};
use prism_recon::MethodConfig;
use prism_recon::device::DeviceChoice;
use prism_recon::evaluate::{Evaluation, rescore};
use prism_recon::methods::classic::import::{import_full, reference_configs, select_views};
use prism_recon::methods::fourdsg::FourDsgMethod;
use prism_recon::methods::fourdsg::ablation::ablate;
use prism_recon::pipeline::{run, run_footprint};
use prism_recon::record::RunDir;
use prism_recon::setup::RunOptions;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

mod state;

use state::read_text;
pub use state::{
    CELL_RECORD, CellRecord, CellState, cell_evaluation, cell_record, read_record, run_state,
    scene_state,
};

/// What every cell is run with.
pub struct ExecOptions<'a> {
    pub observer: &'a dyn Observer,
    /// Where the Gaussian methods run (None: each config's own `device`).
    pub device: Option<DeviceChoice>,
    pub evaluation: &'a Evaluation,
    /// The suite's evaluation settings, recorded in every run cell.
    pub evaluation_spec: &'a EvaluationSpec,
    /// Redo cells whose inputs changed (otherwise they are refused).
    pub force: bool,
    /// Run cells at a time (≥ 1); the threads are split evenly between them.
    pub jobs: usize,
    /// Run a cell even when its estimated peak memory exceeds the memory available (each scene
    /// and run cell is checked before it starts, against what is available then).
    pub allow_memory: bool,
}

impl ExecOptions<'_> {
    /// How each run cell runs under these options: `jobs` at a time on `threads / jobs` threads
    /// each (at least one). `prism experiment` caps `jobs` at the cores; this is also called
    /// inside a cell's own pool, so it must not read the thread count to cap it.
    pub fn execution(&self) -> Execution {
        let jobs = self.jobs.max(1);
        Execution {
            concurrent: jobs,
            threads: (rayon::current_num_threads() / jobs).max(1),
        }
    }
}

/// How a run cell was executed: how many cells ran at once, and the threads it had.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Execution {
    pub concurrent: usize,
    pub threads: usize,
}

/// A cell that failed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Failure {
    pub cell: String,
    pub error: String,
}

/// Make scene cell `i` in `out` (simulate it, or cut it from its imported scan) unless it is
/// done; returns whether it ran.
pub fn make_scene(plan: &Plan, out: &Path, i: usize, options: &ExecOptions) -> Result<bool> {
    let cell = &plan.scenes[i];
    match scene_state(plan, out, i)? {
        CellState::Done => return Ok(false),
        CellState::Changed(why) if !options.force => {
            return Err(changed(why));
        }
        _ => {}
    }
    let mut scene = if cell.import {
        let text = read_text(&cell.config)?;
        let config: ImportConfig =
            prism_domain::yaml::parse_with(&text, &cell.config, &cell.overrides)?;
        let full = full_scan(plan, out, i, &config, &text, options)?;
        select_views(&config, &full).map_err(|e| e.in_file(&cell.config))?
    } else {
        options.observer.note(
            Level::Info,
            &format!("scene {}: simulating {}", cell.key, cell.config.display()),
        );
        let config = SimulateConfig::load_with(&cell.config, &cell.overrides)?;
        config
            .footprint()
            .and_then(|f| f.check(&format!("scene cell `{}`", cell.key), options.allow_memory))
            .map_err(|e| e.in_file(&cell.config))?;
        simulate(&config, Some(&cell.config), options.observer)?
    };
    scene.provenance.overrides = cell.overrides.texts();
    let dir = plan.scene_dir(out, i);
    create_parent(&dir)?;
    scene.save(&dir)?;
    Ok(true)
}

/// The whole measured scan of import scene cell `i` with its references, imported once into
/// `scenes/<scene>-full/` and shared by the scene's cells at every view count (its overrides
/// other than `select.*` recorded, and compared, like a scene's).
fn full_scan(
    plan: &Plan,
    out: &Path,
    i: usize,
    config: &ImportConfig,
    text: &str,
    options: &ExecOptions,
) -> Result<Scene> {
    let cell = &plan.scenes[i];
    let dir = out.join(SCENES).join(format!("{}-full", cell.scene));
    let overrides: Vec<String> = cell
        .overrides
        .texts()
        .into_iter()
        .filter(|o| !o.starts_with("select."))
        .collect();
    if let Ok(scene) = Scene::load(&dir)
        && scene.provenance.config == text
        && scene.provenance.overrides == overrides
    {
        return Ok(scene);
    }
    options.observer.note(
        Level::Info,
        &format!("scene {}: importing {}", cell.scene, cell.config.display()),
    );
    let base = cell.config.parent().unwrap_or(Path::new("."));
    import::footprint(config, base)
        .and_then(|f| f.check(&format!("scene cell `{}`", cell.key), options.allow_memory))
        .map_err(|e| e.in_file(&cell.config))?;
    let references = reference_configs(config, base).map_err(|e| e.in_file(&cell.config))?;
    let mut scene = import_full(config, base, text, references.as_deref(), options.observer)
        .map_err(|e| e.in_file(&cell.config))?;
    scene.provenance.overrides = overrides;
    create_parent(&dir)?;
    scene.save(&dir)?;
    Ok(scene)
}

/// Run cell `i` into `out` unless it is done; returns whether it ran.
pub fn run_cell(plan: &Plan, out: &Path, i: usize, options: &ExecOptions) -> Result<bool> {
    let cell = &plan.runs[i];
    match run_state(plan, out, i, options)? {
        CellState::Done => return Ok(false),
        CellState::Changed(why) if !options.force => return Err(changed(why)),
        CellState::Rescore => return rescore_cell(plan, out, i, options).map(|()| true),
        _ => {}
    }
    let scene_dir = plan.scene_dir(out, cell.scene);
    if scene_state(plan, out, cell.scene)? != CellState::Done {
        return Err(Error::invalid(
            "scene",
            format!(
                "scene cell `{}` is not simulated (or changed); run its scenes first",
                plan.scenes[cell.scene].key
            ),
        ));
    }
    let scene = Scene::load(&scene_dir)?;
    let mut config = MethodConfig::load_with(&cell.config, &cell.overrides)?;
    if let Some(d) = options.device {
        config.set_device(d);
    }
    let evaluation = cell_evaluation(plan, i, options).1;
    let peak = run_footprint(&config, &scene, &evaluation);
    peak.check(&format!("run cell `{}`", cell.key), options.allow_memory)?;
    let record = cell_record(plan, i, options)?;
    let target = plan.run_dir(out, i);
    create_parent(&target)?;
    let mut dir = RunDir::create(&target, true)?;
    dir.write_json(CELL_RECORD, &record)?;
    let run_options = RunOptions {
        device: config.device().device()?,
        from_geometry: None,
        observer: options.observer,
        evaluation: &evaluation,
        checkpoint: None,
    };
    match (cell.kind, &config) {
        (CellKind::Run, _) => {
            run(&config, &scene, dir, &run_options)?;
        }
        (CellKind::Ablation(study), MethodConfig::FourDsg(base)) => {
            ablate(base, study, &scene, dir, &run_options)?;
        }
        (CellKind::Ablation(_), _) => {
            return Err(Error::invalid(
                "method",
                "an ablation needs a `4dsg` config",
            ));
        }
    }
    Ok(true)
}

/// Score finished run cell `i` again under its evaluation now, then record that evaluation in its
/// `cell.json` (each file replaced atomically).
fn rescore_cell(plan: &Plan, out: &Path, i: usize, options: &ExecOptions) -> Result<()> {
    let dir = plan.run_dir(out, i);
    options.observer.note(
        Level::Info,
        &format!(
            "run {}: the evaluation settings changed; scoring its volumes again",
            plan.runs[i].key
        ),
    );
    let scene = Scene::load(plan.scene_dir(out, plan.runs[i].scene))?;
    let (spec, evaluation) = cell_evaluation(plan, i, options);
    rescore(&dir, &scene, &evaluation)?;
    let path = dir.join(CELL_RECORD);
    let mut record: CellRecord = serde_json::from_str(&read_text(&path)?)
        .map_err(|e| Error::field(&path, ".", e.to_string()))?;
    record.evaluation = spec;
    Ok(RunDir::replace_json(&path, &record)?)
}

fn changed(why: String) -> Error {
    Error::invalid(
        "cell",
        format!("{why}; pass --force to redo it (or remove its directory)"),
    )
}

fn create_parent(dir: &Path) -> Result<()> {
    let parent = dir.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))
}

/// Which cells to run.
#[derive(Clone, Debug, Default)]
pub struct Selection {
    /// Only these scene cells (indices), or all.
    pub scenes: Option<Vec<usize>>,
    /// Only these run cells (indices), or all.
    pub runs: Option<Vec<usize>>,
}

impl Selection {
    /// The run cells of the studies named `studies` (all studies when empty) whose key
    /// contains `only` (any key when `None`), and the scene cells they need plus those whose
    /// key contains `only`. Everything when both are absent.
    pub fn of(plan: &Plan, only: Option<&str>, studies: &[String]) -> Result<Selection> {
        if only.is_none() && studies.is_empty() {
            return Ok(Selection::default());
        }
        for name in studies {
            if !plan.studies.iter().any(|s| &s.spec.name == name) {
                let known: Vec<&str> = plan.studies.iter().map(|s| s.spec.name.as_str()).collect();
                return Err(Error::invalid(
                    "--study",
                    format!("no study `{name}` (the suite has: {})", known.join(", ")),
                ));
            }
        }
        let mut in_studies = vec![studies.is_empty(); plan.runs.len()];
        for st in plan
            .studies
            .iter()
            .filter(|s| studies.contains(&s.spec.name))
        {
            for p in &st.points {
                in_studies[p.run] = true;
            }
        }
        let matches = |key: &str| only.is_none_or(|t| key.contains(t));
        let runs: Vec<usize> = (0..plan.runs.len())
            .filter(|&i| in_studies[i] && matches(&plan.runs[i].key))
            .collect();
        let mut scenes: Vec<usize> = runs.iter().map(|&i| plan.runs[i].scene).collect();
        if studies.is_empty() {
            scenes.extend((0..plan.scenes.len()).filter(|&i| matches(&plan.scenes[i].key)));
        }
        scenes.sort_unstable();
        scenes.dedup();
        Ok(Selection {
            scenes: Some(scenes),
            runs: Some(runs),
        })
    }

    /// Whether scene cell `i` is selected.
    pub fn has_scene(&self, i: usize) -> bool {
        self.scenes.as_ref().is_none_or(|s| s.contains(&i))
    }

    /// Whether run cell `i` is selected.
    pub fn has_run(&self, i: usize) -> bool {
        self.runs.as_ref().is_none_or(|r| r.contains(&i))
    }
}

/// Summary of [`run_plan`].
#[derive(Clone, Debug, Default)]
pub struct Executed {
    pub ran: usize,
    pub skipped: usize,
    pub failures: Vec<Failure>,
}

/// Run the selected cells of `plan` (scenes first, in order; then the run cells: in order of
/// their index one at a time, or `jobs` at a time longest first), skipping finished ones;
/// failures are collected, and a run cell whose scene failed is not attempted.
pub fn run_plan(plan: &Plan, out: &Path, sel: &Selection, options: &ExecOptions) -> Executed {
    let done = Mutex::new(Executed::default());
    let mut failed_scenes = std::collections::BTreeSet::new();
    let all_scenes: Vec<usize> = (0..plan.scenes.len()).collect();
    let all_runs: Vec<usize> = (0..plan.runs.len()).collect();
    let scenes = sel.scenes.as_ref().unwrap_or(&all_scenes);
    let runs = sel.runs.as_ref().unwrap_or(&all_runs);
    let tally = |key: &str, r: Result<bool>| {
        let mut done = done.lock().unwrap_or_else(|p| p.into_inner());
        match r {
            Ok(true) => done.ran += 1,
            Ok(false) => done.skipped += 1,
            Err(e) => {
                let e = e.in_cell(key);
                options.observer.note(Level::Warning, &e.to_string());
                done.failures.push(Failure {
                    cell: key.to_string(),
                    error: e.to_string(),
                });
            }
        }
    };
    for &i in scenes {
        let r = make_scene(plan, out, i, options);
        if r.is_err() {
            failed_scenes.insert(i);
        }
        tally(&format!("scenes/{}", plan.scenes[i].key), r);
    }
    let started = AtomicUsize::new(0);
    let one = |k: usize, observer: &dyn Observer| {
        let i = runs[k];
        let key = format!("runs/{}", plan.runs[i].key);
        if failed_scenes.contains(&plan.runs[i].scene) {
            tally(&key, Err(Error::invalid("scene", "its scene failed")));
            return;
        }
        let nth = started.fetch_add(1, Ordering::Relaxed) + 1;
        options.observer.note(
            Level::Info,
            &format!("[{nth}/{}] {}", runs.len(), plan.runs[i].key),
        );
        let cell_options = ExecOptions {
            observer,
            ..*options
        };
        tally(&key, run_cell(plan, out, i, &cell_options));
    };
    let execution = options.execution();
    if execution.concurrent == 1 {
        (0..runs.len()).for_each(|k| one(k, options.observer));
    } else {
        // Longest first, so that no long cell starts last and runs alone (a rough cost).
        let mut order: Vec<usize> = (0..runs.len()).collect();
        order.sort_by_key(|&k| std::cmp::Reverse(rough_cost(plan, runs[k])));
        let (next, finished) = (AtomicUsize::new(0), AtomicUsize::new(0));
        options.observer.phase(
            &format!("{} at a time", execution.concurrent),
            runs.len() as u64,
        );
        std::thread::scope(|scope| {
            for _ in 0..execution.concurrent {
                scope.spawn(|| {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(execution.threads)
                        .build();
                    while let Some(&k) = order.get(next.fetch_add(1, Ordering::Relaxed)) {
                        let observer = Tagged {
                            inner: options.observer,
                            cell: &plan.runs[runs[k]].key,
                        };
                        match &pool {
                            Ok(pool) => pool.install(|| one(k, &observer)),
                            Err(e) => tally(
                                &format!("runs/{}", plan.runs[runs[k]].key),
                                Err(Error::invalid("jobs", format!("no thread pool: {e}"))),
                            ),
                        }
                        let n = finished.fetch_add(1, Ordering::Relaxed) + 1;
                        options
                            .observer
                            .progress(n as u64, &format!("finished {}", observer.cell));
                    }
                });
            }
        });
    }
    done.into_inner().unwrap_or_else(|p| p.into_inner())
}

/// A rough relative cost of run cell `i`, to order cells run at a time: trained models
/// (channels, or one shared model per channel count) times their iterations, times the
/// variants of an ablation; classic methods (seconds) cost nothing. Unreadable configs sort
/// first (they fail at once).
fn rough_cost(plan: &Plan, i: usize) -> u64 {
    let cell = &plan.runs[i];
    let channels = plan.scenes[cell.scene].channels;
    let Ok(config) = MethodConfig::load_with(&cell.config, &cell.overrides) else {
        return u64::MAX;
    };
    let base = match &config {
        MethodConfig::Classic(_) => 0,
        MethodConfig::R2gs(r) => (r.geometry.iterations * channels) as u64,
        MethodConfig::FourDsg(g) => {
            let per_channel = match g.method {
                FourDsgMethod::Stage1 => g.spectral.density_iterations,
                FourDsgMethod::Full => g.spectral.stage2.iterations,
            };
            (g.geometry.iterations + per_channel * channels) as u64
        }
        MethodConfig::Naf(n) => (n.iterations * channels * 4) as u64,
    };
    match (cell.kind, &config) {
        (CellKind::Ablation(study), MethodConfig::FourDsg(g)) => {
            base * study.variants(g).len() as u64
        }
        _ => base,
    }
}

/// The observer of a cell that runs beside others: its notes, prefixed with the cell, reach the
/// suite's observer; its phases and progress (which would fight over one bar) do not.
struct Tagged<'a> {
    inner: &'a dyn Observer,
    cell: &'a str,
}

impl Observer for Tagged<'_> {
    fn note(&self, level: Level, text: &str) {
        self.inner.note(level, &format!("{}: {text}", self.cell));
    }
}

/// `failures.json` under the output: the failures of the last run (removed when none).
pub fn record_failures(out: &Path, failures: &[Failure]) -> Result<PathBuf> {
    let path = out.join("failures.json");
    if failures.is_empty() {
        if path.exists() {
            std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
        }
    } else {
        let json = serde_json::to_string_pretty(failures)
            .map_err(|e| Error::field(&path, ".", e.to_string()))?;
        std::fs::write(&path, json + "\n").map_err(|e| Error::io(&path, e))?;
    }
    Ok(path)
}
