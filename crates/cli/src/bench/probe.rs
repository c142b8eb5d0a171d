//! The clock and the allocator's counters after every training iteration, per stage: what the
//! iteration benchmarks read their per-iteration costs from.

use crate::alloc::{Allocated, allocated};
use crate::progress::Bars;
use prism_domain::observe::{Level, Observer};
use prism_domain::scene::Scene;
use prism_recon::MethodConfig;
use prism_recon::evaluate::Evaluation;
use prism_recon::gaussians::train::StageReport;
use prism_recon::record::RunDir;
use prism_recon::setup::RunOptions;
use std::sync::Mutex;
use std::time::Instant;

/// The clock and the allocator's counters after one iteration.
pub type Sample = (Instant, Allocated);

/// A phase's name and the samples after each of its iterations.
pub type Phase = (String, Vec<Sample>);

/// Samples after each iteration of each phase (named as the run names it).
#[derive(Default)]
pub struct Probe {
    stages: Mutex<Vec<Phase>>,
}

impl Probe {
    /// The phases seen, each with its samples, in order.
    pub fn into_stages(self) -> Vec<Phase> {
        self.stages.into_inner().unwrap_or_else(|e| e.into_inner())
    }
}

impl Observer for Probe {
    fn phase(&self, name: &str, _total: u64) {
        let mut s = self.stages.lock().unwrap_or_else(|e| e.into_inner());
        s.push((name.to_string(), Vec::new()));
    }
    fn progress(&self, _done: u64, _status: &str) {
        let sample = (Instant::now(), allocated());
        let mut s = self.stages.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(last) = s.last_mut() {
            last.1.push(sample);
        }
    }
}

/// Forwards to the progress bars (when shown) and records into the probe.
pub struct Both<'a>(pub Option<&'a Bars>, pub &'a Probe);

impl Observer for Both<'_> {
    fn phase(&self, name: &str, total: u64) {
        if let Some(b) = self.0 {
            b.phase(name, total);
        }
        self.1.phase(name, total);
    }
    fn progress(&self, done: u64, status: &str) {
        self.1.progress(done, status);
        if let Some(b) = self.0 {
            b.progress(done, status);
        }
    }
    fn note(&self, level: Level, text: &str) {
        if let Some(b) = self.0 {
            b.note(level, text);
        }
    }
}

/// Run `config` on `scene` in a temporary directory with a probe (and the progress bars, when
/// given): the phases with their samples, and, for a Gaussian method (`gaussian`), the stage
/// reports of its `train.json`.
pub fn probed_run(
    config: &MethodConfig,
    scene: &Scene,
    evaluation: &Evaluation,
    bars: Option<&Bars>,
    gaussian: bool,
) -> anyhow::Result<(Vec<Phase>, Vec<StageReport>)> {
    let tmp = tempfile::tempdir()?;
    let probe = Probe::default();
    let observer = Both(bars, &probe);
    let options = RunOptions {
        device: config.device().device()?,
        from_geometry: None,
        observer: &observer,
        evaluation,
        checkpoint: None,
    };
    let dir = RunDir::create(&tmp.path().join("run"), false)?;
    let outcome = prism_recon::pipeline::run(config, scene, dir, &options)?;
    let reports = if gaussian {
        let train: serde_json::Value = RunDir::read_json(&outcome.dir.join(RunDir::TRAIN))?;
        serde_json::from_value(train["stages"].clone())?
    } else {
        Vec::new()
    };
    Ok((probe.into_stages(), reports))
}
