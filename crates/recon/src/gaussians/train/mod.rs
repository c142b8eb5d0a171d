//! Training a Gaussian model, shared by R²-Gaussian, 4D-SG stage 1, the per-channel density fit
//! and stage 2.
//!
//! [`Trainer::step`] does one iteration; [`train`] is the loop around it that owns *when*
//! things happen: the learning-rate schedule (log-linear per group, [`LearningRates`]), the
//! densification window ([`DensifyConfig`]), evaluation against reference volumes every
//! `eval_every` iterations (its time is kept out of the training time), the records of
//! `log.jsonl` ([`log`]) and progress reports to an [`Observer`].

pub mod checkpoints;
pub mod data;
pub mod data_term;
pub mod densify;
mod draw;
pub mod evaluator;
pub mod head;
pub mod loss;
pub mod settings;
pub mod ssim;
pub mod trainer;
pub mod tv;

pub use checkpoints::Checkpoints;
pub use data::{Supervision, View};
pub use densify::DensifyCounts;
pub use evaluator::Evaluator;
pub use head::{ChannelMix, DensityNet, common_density};
pub use settings::{ChannelMap, Stage};
pub use trainer::{DensifyStep, StepPlan, StepStats, Trainer, TrainerState};

use crate::gaussians::GaussianModel;
use crate::gaussians::adam::LogLinear;
use crate::gaussians::config::{DensifyConfig, LearningRates};
use crate::record::log::{LogRecord, LossTerms, RunLog};
use crate::{Error, Result};
use prism_domain::observe::{Level, Observer};
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
/// (`train.json`), where progress goes and, when on, its checkpoints ([`resume`]).
pub struct Journal<'a> {
    pub log: RunLog,
    pub stages: Vec<StageReport>,
    pub observer: &'a dyn Observer,
    pub checkpoints: Option<Checkpoints<'a>>,
    /// Stages trained (or replayed from a checkpoint) so far.
    trained: usize,
}

impl<'a> Journal<'a> {
    pub fn new(log: RunLog, observer: &'a dyn Observer) -> Self {
        Journal {
            log,
            stages: Vec::new(),
            observer,
            checkpoints: None,
            trained: 0,
        }
    }

    /// [`train`] one stage and keep its summary. With checkpoints resuming a run, a stage the
    /// saved run finished is restored instead (its model, curve model, summary and log), and
    /// the stage it was in continues from its saved iteration.
    pub fn train(
        &mut self,
        model: &mut GaussianModel,
        sup: &Supervision,
        eval: Option<&Evaluator>,
        stage: &Stage,
        mut curve: Option<&mut dyn DensityNet>,
    ) -> Result<()> {
        let index = self.trained;
        self.trained += 1;
        let mut start = None;
        if let Some(ck) = &mut self.checkpoints {
            if let Some((report, log)) = ck.replay(index, stage, model, curve.as_deref_mut())? {
                self.log.restore(&log)?;
                self.stages.push(report);
                return Ok(());
            }
            if let Some((trainer, progress, log)) =
                ck.take_current(index, stage, model, curve.as_deref_mut())?
            {
                self.log.restore(&log)?;
                self.observer.note(
                    Level::Info,
                    &format!(
                        "resuming {} {} after iteration {} of {}",
                        stage.name, stage.channel, progress.iteration, stage.iterations
                    ),
                );
                start = Some((trainer, progress));
            }
        }
        let at = StageStart {
            index,
            resumed: start,
        };
        let r = train(self, at, model, sup, eval, stage, curve.as_deref_mut())?;
        if let Some(ck) = &mut self.checkpoints {
            ck.finished(stage, model, curve.as_deref(), &r, self.log.saved())?;
        }
        self.stages.push(r);
        Ok(())
    }
}

/// A stage's running sums between two iterations (saved with a checkpoint).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    /// Iterations done.
    pub iteration: usize,
    /// The run's training seconds when the stage started.
    pub start_train_s: f64,
    pub timing: Timing,
    pub counts: DensifyCounts,
    /// Loss terms summed since the last log record, and their count.
    pub window: LossTerms,
    pub window_n: usize,
    pub last: LossTerms,
    /// The last (PSNR, SSIM).
    pub last_score: Option<(f64, f64)>,
}

impl Progress {
    /// Refuse running sums that cannot come from a run of `iterations` iterations (saved in
    /// `file`'s `metadata.current.progress`).
    pub fn check(&self, iterations: usize, file: &std::path::Path) -> Result<()> {
        use crate::record::resume::{check_iteration, check_sum};
        let field = |f: &str| format!("metadata.current.progress.{f}");
        check_iteration(self.iteration, iterations, file, &field("iteration"))?;
        if self.window_n > self.iteration {
            return Err(Error::field(
                file,
                field("window_n"),
                format!(
                    "{} iterations since the last record, {} done",
                    self.window_n, self.iteration
                ),
            ));
        }
        let t = &self.timing;
        let sums = [
            ("start_train_s", self.start_train_s),
            ("timing.render", t.render),
            ("timing.loss", t.loss),
            ("timing.backward", t.backward),
            ("timing.optimiser", t.optimiser),
            ("timing.densify", t.densify),
        ];
        for (name, v) in sums {
            check_sum(v, file, &field(name))?;
        }
        for (group, l) in [("window", &self.window), ("last", &self.last)] {
            for (name, v) in [
                ("total", l.total),
                ("l1", l.l1),
                ("dssim", l.dssim),
                ("tv", l.tv),
                ("curve", l.curve),
            ] {
                check_sum(v, file, &field(&format!("{group}.{name}")))?;
            }
        }
        if let Some((psnr, ssim)) = self.last_score
            && (psnr.is_nan() || !(-1.0..=1.0).contains(&ssim))
        {
            return Err(Error::field(
                file,
                field("last_score"),
                format!("({psnr}, {ssim}) is not a (PSNR, SSIM) pair"),
            ));
        }
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

/// The score of a model in training (through its density network or channel mix, if any).
fn score(e: &Evaluator, t: &Trainer, stage: &Stage) -> Result<(f64, f64)> {
    match (t.curve(), stage.map) {
        (Some(c), _) => e.score_raw(t.model(), c.raw_densities(t.model())?),
        (None, ChannelMap::Mix(h)) => e.score_raw(t.model(), h.channel_raw(t.model())),
        (None, ChannelMap::Direct) => e.score(t.model()),
    }
}

/// Where a stage starts: its index in the run's sequence of stages, and the saved trainer state
/// and running sums it continues from (a checkpoint's), if any.
struct StageStart {
    index: usize,
    resumed: Option<(TrainerState, Progress)>,
}

/// Train `model` (and, in stage 2, `curve`) on `sup` for one stage, from `at`, scoring against
/// `eval` when given; records go to the journal's log, progress to its observer, state to its
/// checkpoints.
fn train(
    journal: &mut Journal,
    at: StageStart,
    model: &mut GaussianModel,
    sup: &Supervision,
    eval: Option<&Evaluator>,
    stage: &Stage,
    curve: Option<&mut dyn DensityNet>,
) -> Result<StageReport> {
    let StageStart { index, resumed } = at;
    let schedule = Schedule {
        iterations: stage.iterations,
        lr: stage.lr,
        network: curve.as_ref().map(|c| c.lr()),
        densify: stage.densification(),
        eval_every: stage.eval_every,
    };
    let mut trainer = Trainer::new(model, sup, stage, curve)?;
    let mut p = match resumed {
        Some((state, progress)) => {
            let file = journal
                .checkpoints
                .as_ref()
                .map(|c| c.file().path().to_path_buf())
                .unwrap_or_default();
            trainer.restore(state, &file)?;
            progress
        }
        None => Progress {
            start_train_s: journal.log.train_s(),
            ..Progress::default()
        },
    };
    let mut status = String::new();
    let observer = journal.observer;
    observer.phase(
        &format!("{} {}", stage.name, stage.channel),
        stage.iterations as u64,
    );
    if p.iteration > 0 {
        // A resumed stage: the bar starts where the saved run stopped.
        observer.progress(p.iteration as u64, &status);
    }

    for it in p.iteration + 1..=stage.iterations {
        let cursor = journal.checkpoints.as_ref().map(|_| trainer.cursor());
        let step = match trainer.step(&schedule.plan(it)) {
            Ok(step) => step,
            Err(Error::Diverged {
                stage: s,
                iter,
                detail,
            }) => {
                let saved = match (&mut journal.checkpoints, cursor) {
                    (Some(ck), Some(before)) => {
                        let log = journal.log.saved();
                        ck.save_last_good(index, stage, &mut trainer, before, &p, log)?
                    }
                    _ => String::new(),
                };
                return Err(Error::Diverged {
                    stage: s,
                    iter,
                    detail: format!("{detail}{saved}"),
                });
            }
            Err(e) => return Err(e),
        };
        p.iteration = it;
        p.timing.add(&step.timing);
        if let Some(c) = step.densified {
            p.counts.cloned += c.cloned;
            p.counts.split += c.split;
            p.counts.pruned += c.pruned;
        }
        p.window.add(&step.loss);
        p.window_n += 1;
        p.last = step.loss;

        let due = schedule.evaluates(it);
        if due {
            let log = &mut journal.log;
            let score = match eval {
                Some(e) => Some(log.evaluating(|| score(e, &trainer, stage))?),
                None => None,
            };
            if score.is_some() {
                p.last_score = score;
            }
            let (acc, k) = (
                std::mem::take(&mut p.window),
                std::mem::take(&mut p.window_n),
            );
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
            let psnr = p
                .last_score
                .map(|s| format!(" PSNR {:.2}", s.0))
                .unwrap_or_default();
            status = format!(
                "loss {:.4e} K {}{psnr}",
                p.last.total,
                trainer.model().len()
            );
        }
        observer.progress(it as u64, &status);

        if let Some(ck) = &mut journal.checkpoints {
            let stop = ck.file().stop_requested();
            if stop || ck.file().due(it) {
                // Writing a checkpoint is not training time.
                let saved = journal.log.saved();
                let log = &mut journal.log;
                log.evaluating(|| ck.save(index, stage, &trainer, &p, saved))?;
            }
            if stop {
                return Err(Error::Interrupted {
                    stage: format!("{} {}", stage.name, stage.channel),
                    iter: it,
                    checkpoint: ck.file().path().to_path_buf(),
                });
            }
        }
    }
    Ok(StageReport {
        stage: stage.name.to_string(),
        channel: stage.channel.to_string(),
        iterations: stage.iterations,
        train_s: journal.log.train_s() - p.start_train_s,
        timing: p.timing,
        densify: p.counts,
        n_gaussians: trainer.model().len(),
        final_loss: p.last,
        psnr: p.last_score.map(|s| s.0),
        ssim: p.last_score.map(|s| s.1),
    })
}
