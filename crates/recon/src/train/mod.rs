//! Training a Gaussian model, shared by R²-Gaussian, 4D-SG stage 1, the per-channel density fit
//! and stage 2.
//!
//! [`Trainer::step`] does one iteration; [`train`] is the loop around it that owns *when*
//! things happen: the learning-rate schedule (log-linear per group, [`LearningRates`]), the
//! densification window ([`DensifyConfig`]), evaluation against reference volumes every
//! `eval_every` iterations (its time is kept out of the training time), the records of
//! `log.jsonl` ([`log`]) and progress reports to an [`Observer`].

pub mod curve;
pub mod data;
pub mod densify;
pub mod log;
pub mod loss;
pub mod settings;
pub mod trainer;

pub use curve::CurveFit;
pub use data::{Supervision, View};
pub use densify::DensifyCounts;
pub use log::{LogRecord, LossTerms, RunLog};
pub use settings::Stage;
pub use trainer::{DensifyStep, StepPlan, StepStats, Trainer};

use crate::Result;
use crate::evaluate::Evaluator;
use crate::gaussian::GaussianModel;
use crate::gaussian::adam::LogLinear;
use crate::gaussian::config::{DensifyConfig, LearningRates};
use prism_domain::observe::Observer;
use serde::{Deserialize, Serialize};

/// Seconds spent per part of an iteration (one step, or summed over a stage). On the CPU
/// backends each part is its own work; on wgpu the ops only queue, and the forward and backward
/// are paid where the loss terms are read back, which is counted under `backward`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    pub render: f64,
    pub loss: f64,
    pub backward: f64,
    pub optimiser: f64,
    pub densify: f64,
}

impl Timing {
    fn add(&mut self, o: &Timing) {
        self.render += o.render;
        self.loss += o.loss;
        self.backward += o.backward;
        self.optimiser += o.optimiser;
        self.densify += o.densify;
    }
}

/// Summary of one stage (an entry of `train.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    pub stage: String,
    pub channel: String,
    pub iterations: usize,
    /// Training seconds of this stage (evaluation excluded).
    pub train_s: f64,
    pub timing: Timing,
    pub densify: DensifyCounts,
    pub n_gaussians: usize,
    pub final_loss: LossTerms,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
}

/// A run's training record: its log (`log.jsonl`), the summaries of the stages trained so far
/// (`train.json`) and where progress goes.
pub struct Journal<'a> {
    pub log: RunLog,
    pub stages: Vec<StageReport>,
    pub observer: &'a dyn Observer,
}

impl<'a> Journal<'a> {
    pub fn new(log: RunLog, observer: &'a dyn Observer) -> Self {
        Journal {
            log,
            stages: Vec::new(),
            observer,
        }
    }

    /// [`train`] one stage and keep its summary.
    pub fn train(
        &mut self,
        model: &mut GaussianModel,
        sup: &Supervision,
        eval: Option<&Evaluator>,
        stage: &Stage,
        curve: Option<&mut CurveFit>,
    ) -> Result<()> {
        let r = train(model, sup, eval, stage, curve, &mut self.log, self.observer)?;
        self.stages.push(r);
        Ok(())
    }
}

/// When what happens in a stage.
struct Schedule<'a> {
    iterations: usize,
    lr: &'a LearningRates,
    network: Option<LogLinear>,
    densify: Option<&'a DensifyConfig>,
    eval_every: usize,
}

impl Schedule<'_> {
    fn plan(&self, it: usize) -> StepPlan {
        let t = it - 1;
        let densify = match self.densify {
            Some(d) if it < d.until && d.due(it) => DensifyStep::Apply,
            Some(d) if it < d.until => DensifyStep::Accumulate,
            _ => DensifyStep::Off,
        };
        StepPlan {
            iteration: it,
            rates: self.lr.at(t, self.iterations),
            network_lr: self.network.map_or(0.0, |n| n.at(t, self.iterations)),
            densify,
        }
    }

    /// Whether iteration `it` ends with an evaluation and a log record.
    fn evaluates(&self, it: usize) -> bool {
        (self.eval_every > 0 && it.is_multiple_of(self.eval_every)) || it == self.iterations
    }
}

/// The score of a model in training (through its curve model in stage 2).
fn score(e: &Evaluator, t: &Trainer) -> Result<(f64, f64)> {
    match t.curve() {
        Some(c) => e.score_raw(t.model(), c.raw_densities(t.model())?),
        None => e.score(t.model()),
    }
}

/// Train `model` (and, in stage 2, `curve`) on `sup` for one stage, scoring against `eval` when
/// given; records go to `log`, progress to `observer`.
pub fn train(
    model: &mut GaussianModel,
    sup: &Supervision,
    eval: Option<&Evaluator>,
    stage: &Stage,
    curve: Option<&mut CurveFit>,
    log: &mut RunLog,
    observer: &dyn Observer,
) -> Result<StageReport> {
    let schedule = Schedule {
        iterations: stage.iterations,
        lr: stage.lr,
        network: curve.as_ref().map(|c| c.lr),
        densify: stage.densification(),
        eval_every: stage.eval_every,
    };
    let mut trainer = Trainer::new(model, sup, stage, curve)?;
    let start_train = log.train_s();
    let mut timing = Timing::default();
    let mut counts = DensifyCounts::default();
    let mut window = (LossTerms::default(), 0usize);
    let mut last = LossTerms::default();
    let mut last_score: Option<(f64, f64)> = None;
    let mut status = String::new();
    observer.phase(
        &format!("{} {}", stage.name, stage.channel),
        stage.iterations as u64,
    );

    for it in 1..=stage.iterations {
        let step = trainer.step(&schedule.plan(it))?;
        timing.add(&step.timing);
        if let Some(c) = step.densified {
            counts.cloned += c.cloned;
            counts.split += c.split;
            counts.pruned += c.pruned;
        }
        window.0.add(&step.loss);
        window.1 += 1;
        last = step.loss;

        let due = schedule.evaluates(it);
        if due {
            let score = match eval {
                Some(e) => Some(log.evaluating(|| score(e, &trainer))?),
                None => None,
            };
            if score.is_some() {
                last_score = score;
            }
            let (acc, k) = std::mem::take(&mut window);
            log.write(&LogRecord {
                stage: stage.name.to_string(),
                channel: stage.channel.to_string(),
                iter: it,
                wall_s: log.wall_s(),
                train_s: log.train_s(),
                loss: acc.mean_of(k),
                n_gaussians: Some(trainer.model().len()),
                psnr: score.map(|s| s.0),
                ssim: score.map(|s| s.1),
            })?;
        }
        if due || it % 10 == 0 {
            let psnr = last_score
                .map(|s| format!(" PSNR {:.2}", s.0))
                .unwrap_or_default();
            status = format!("loss {:.4e} K {}{psnr}", last.total, trainer.model().len());
        }
        observer.progress(it as u64, &status);
    }
    Ok(StageReport {
        stage: stage.name.to_string(),
        channel: stage.channel.to_string(),
        iterations: stage.iterations,
        train_s: log.train_s() - start_train,
        timing,
        densify: counts,
        n_gaussians: trainer.model().len(),
        final_loss: last,
        psnr: last_score.map(|s| s.0),
        ssim: last_score.map(|s| s.1),
    })
}
