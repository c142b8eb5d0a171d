//! Interrupting and resuming a Gaussian run: the state of every stage trained so far in one
//! file.
//!
//! A Gaussian run is a fixed sequence of training stages (R²-Gaussian: one per channel; 4D-SG:
//! stage 1, then the spectral stage), trained in order by the [`Journal`](super::Journal). With
//! [`Checkpoints`] it writes the run's state to one file:
//! * every `checkpoint_every` iterations of a stage (0: never on a schedule);
//! * when the run is asked to stop (the `prism` binary's SIGINT / SIGTERM handler sets the flag;
//!   the current step finishes first);
//! * when a stage diverges: the state before the failing step, when its parameters are finite
//!   (else the last file written stays, and the error says so).
//!
//! The file holds every finished stage's final model (raw parameters and Adam state), curve
//! model (network and optimiser records), summary and the log at its end; and the stage in
//! progress: its model and curve model, the trainer's state ([`TrainerState`]: random stream,
//! view order, densification statistics), the stage's running sums ([`Progress`]) and the log so
//! far. A run resumed from it replays the finished stages (their models restored, not trained
//! again) and continues the stage in progress from the next iteration; on the same device the
//! result equals the uninterrupted run's bit for bit (tests check R²-Gaussian and both 4D-SG
//! stages on the CPU). A file from another scene, other settings or another sequence of stages
//! is refused, naming what differs.
//!
//! Format: safetensors `prism-resume/1`. Tensors: `done<i>.` and `current.` prefixes on a
//! [`ModelState`]'s groups, `<prefix>net` and `<prefix>optim` (u8: Burn's records of the curve
//! model and its Adam), `current.stats.sum` / `current.stats.count` (f32 `[K,1]`). Metadata
//! (JSON): `format`, `fingerprint`, `done` (per finished stage: name, channel, model meta,
//! whether a curve model is stored, summary, log) and `current` (the same for the stage in
//! progress, with its index, trainer state and running sums).

use super::head::DensityNet;
use super::trainer::{Cursor, Trainer, TrainerState};
use super::{Progress, Stage, StageReport};
use crate::gaussians::GaussianModel;
use crate::gaussians::state::{ModelMeta, ModelState};
use crate::record::log::SavedLog;
use crate::record::tensors::{TensorFile, Tensors, json_meta};
use crate::{Error, Result};
use burn::tensor::Device;
use serde::{Deserialize, Serialize};

pub(crate) use crate::record::resume::NetState;
pub use crate::record::resume::ResumeFile;

const FORMAT: &str = "prism-resume/1";

/// One stage's saved state: its model and curve model, and the log at that point.
#[derive(Clone, Debug)]
struct Snapshot {
    stage: String,
    channel: String,
    model: ModelState,
    curve: Option<NetState>,
    log: SavedLog,
}

/// The metadata of a [`Snapshot`] (its tensors are stored apart).
#[derive(Clone, Debug, Serialize, Deserialize)]
struct SnapshotMeta {
    stage: String,
    channel: String,
    model: ModelMeta,
    curve: bool,
    log: SavedLog,
}

/// A finished stage: its final state and summary.
#[derive(Clone, Debug)]
struct Finished {
    at: Snapshot,
    report: StageReport,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct FinishedMeta {
    #[serde(flatten)]
    at: SnapshotMeta,
    report: StageReport,
}

/// The stage in progress: its state after `progress.iteration` iterations.
#[derive(Clone, Debug)]
pub struct Current {
    index: usize,
    at: Snapshot,
    trainer: TrainerState,
    pub progress: Progress,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct CurrentMeta {
    index: usize,
    #[serde(flatten)]
    at: SnapshotMeta,
    trainer: TrainerState,
    stats: bool,
    progress: Progress,
}

/// Where a run saves its state, when, and what it resumes from (see the module docs).
pub struct Checkpoints<'a> {
    file: ResumeFile<'a>,
    /// The stages finished so far (host copies, to write with every checkpoint).
    done: Vec<Finished>,
    /// What the resume file held and this run has not replayed yet.
    resume: Option<(Vec<Finished>, Option<Current>)>,
    /// (stage index, iteration) of the last file written.
    written: Option<(usize, usize)>,
    /// The run continues the state read from the file.
    resumed: bool,
}

impl<'a> Checkpoints<'a> {
    /// Checkpoints saved to and resumed from `file`.
    pub fn new(file: ResumeFile<'a>) -> Self {
        Checkpoints {
            file,
            done: Vec::new(),
            resume: None,
            written: None,
            resumed: false,
        }
    }

    /// Continue the run saved in this checkpoint's file (refused when it belongs to another
    /// scene or settings).
    pub fn resume_from_file(mut self) -> Result<Self> {
        let f = self.file.open(FORMAT)?;
        let path = f.path().to_path_buf();
        let done_meta: Vec<FinishedMeta> = f.json("done")?;
        let done = done_meta
            .into_iter()
            .enumerate()
            .map(|(i, m)| {
                Ok(Finished {
                    at: read_snapshot(&f, &format!("done{i}."), m.at)?,
                    report: m.report,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let current_meta: Option<CurrentMeta> = f.json("current")?;
        let current = match current_meta {
            None => None,
            Some(m) => {
                let at = read_snapshot(&f, "current.", m.at)?;
                let mut trainer = m.trainer;
                if m.stats {
                    let k = at.model.len();
                    let stat = |name: &str| -> Result<Vec<f32>> {
                        let v = f.rows(name, 1)?;
                        if v.len() != k {
                            return Err(Error::field(
                                &path,
                                name,
                                format!("expected {k} rows, got {}", v.len()),
                            ));
                        }
                        Ok(v)
                    };
                    trainer.stats =
                        Some((stat("current.stats.sum")?, stat("current.stats.count")?));
                }
                if m.index != done.len() {
                    return Err(Error::field(
                        &path,
                        "metadata.current.index",
                        format!("stage {} follows {} finished stages", m.index, done.len()),
                    ));
                }
                Some(Current {
                    index: m.index,
                    at,
                    trainer,
                    progress: m.progress,
                })
            }
        };
        self.resume = Some((done, current));
        self.resumed = true;
        Ok(self)
    }

    /// Where, when and against what the checkpoints are saved.
    pub fn file(&self) -> &ResumeFile<'a> {
        &self.file
    }

    /// The `index`-th stage of this run, when the resume file finished it: its model (and curve
    /// model) restored into `model` and `curve`, its summary and its log. The stage must be the
    /// one the file recorded.
    pub(super) fn replay(
        &mut self,
        index: usize,
        stage: &Stage,
        model: &mut GaussianModel,
        curve: Option<&mut dyn DensityNet>,
    ) -> Result<Option<(StageReport, SavedLog)>> {
        let Some((done, _)) = &self.resume else {
            return Ok(None);
        };
        let Some(f) = done.get(index).cloned() else {
            return Ok(None);
        };
        self.check_stage(index, &f.at, stage)?;
        self.restore(&f.at, model, curve, &format!("done{index}."))?;
        let out = (f.report.clone(), f.at.log.clone());
        self.done.push(f);
        Ok(Some(out))
    }

    /// The `index`-th stage's state in progress, when the resume file holds it: restored into
    /// `model` and `curve`; the trainer's state and the running sums are returned.
    pub(super) fn take_current(
        &mut self,
        index: usize,
        stage: &Stage,
        model: &mut GaussianModel,
        curve: Option<&mut dyn DensityNet>,
    ) -> Result<Option<(TrainerState, Progress, SavedLog)>> {
        let Some((done, current)) = &mut self.resume else {
            return Ok(None);
        };
        if index < done.len() {
            return Ok(None);
        }
        let Some(c) = current.take() else {
            return Err(Error::field(
                self.file.path(),
                "metadata.done",
                format!(
                    "the checkpoint holds {} finished stages and no stage in progress, this run \
                     trains more",
                    done.len()
                ),
            ));
        };
        self.check_stage(c.index, &c.at, stage)?;
        c.progress.check(stage.iterations, self.file.path())?;
        self.restore(&c.at, model, curve, "current.")?;
        self.resume = None;
        Ok(Some((c.trainer, c.progress, c.at.log)))
    }

    fn check_stage(&self, index: usize, at: &Snapshot, stage: &Stage) -> Result<()> {
        if at.stage != stage.name || at.channel != stage.channel {
            return Err(Error::field(
                self.file.path(),
                "metadata",
                format!(
                    "the checkpoint's stage {index} is `{} {}`, this run's is `{} {}`: resume \
                     with the options of the interrupted run",
                    at.stage, at.channel, stage.name, stage.channel
                ),
            ));
        }
        Ok(())
    }

    fn restore(
        &self,
        at: &Snapshot,
        model: &mut GaussianModel,
        curve: Option<&mut dyn DensityNet>,
        prefix: &str,
    ) -> Result<()> {
        let device: Device = model.device();
        if at.model.meta().channels != model.channels() {
            return Err(Error::field(
                self.file.path(),
                format!("{prefix}densities_raw"),
                format!(
                    "{} density columns saved, this stage trains {}",
                    at.model.meta().channels,
                    model.channels()
                ),
            ));
        }
        *model = at.model.to_model(&device);
        match (curve, &at.curve) {
            (Some(c), Some(s)) => c.restore(s, self.file.path(), prefix),
            (None, None) => Ok(()),
            (c, _) => Err(Error::field(
                self.file.path(),
                format!("{prefix}net"),
                format!(
                    "the checkpoint {} a curve model, this stage {}",
                    if at.curve.is_some() { "has" } else { "has no" },
                    if c.is_some() {
                        "trains one"
                    } else {
                        "has none"
                    }
                ),
            )),
        }
    }

    /// Keep a finished stage's final state for the checkpoints that follow.
    pub(super) fn finished(
        &mut self,
        stage: &Stage,
        model: &GaussianModel,
        curve: Option<&dyn DensityNet>,
        report: &StageReport,
        log: SavedLog,
    ) -> Result<()> {
        self.done.push(Finished {
            at: Snapshot {
                stage: stage.name.to_string(),
                channel: stage.channel.to_string(),
                model: ModelState::of(model),
                curve: curve.map(|c| c.state()).transpose()?,
                log,
            },
            report: report.clone(),
        });
        Ok(())
    }

    /// Write the run's state with the stage in progress (`index`-th, `trainer`'s model after
    /// `progress.iteration` iterations) to the checkpoint file, atomically.
    pub(super) fn save(
        &mut self,
        index: usize,
        stage: &Stage,
        trainer: &Trainer,
        progress: &Progress,
        log: SavedLog,
    ) -> Result<()> {
        let current = Self::current(index, stage, trainer, progress, log)?;
        self.write(&current)
    }

    /// After the `index`-th stage diverged in the step that followed `progress`: rewind the
    /// trainer to before that step (the step changed only its random stream and view order)
    /// and save that state when its parameters are finite. Says where the last good state is,
    /// for the error.
    pub(super) fn save_last_good(
        &mut self,
        index: usize,
        stage: &Stage,
        trainer: &mut Trainer,
        before: Cursor,
        progress: &Progress,
        log: SavedLog,
    ) -> Result<String> {
        trainer.rewind(before);
        let current = Self::current(index, stage, trainer, progress, log)?;
        let path = self.file.path().display().to_string();
        if current.at.model.is_finite() {
            self.write(&current)?;
            return Ok(format!(
                "; the state before it (iteration {}) is saved in `{path}`",
                progress.iteration
            ));
        }
        Ok(match self.written {
            Some((i, at)) => format!(
                "; its parameters are not finite, the last good state (stage {i}, iteration \
                 {at}) is in `{path}`"
            ),
            None if self.resumed => format!(
                "; its parameters are not finite; the run resumed from `{path}` (no state was \
                 saved since)"
            ),
            None => "; its parameters are not finite and no earlier state was saved (set \
                     `checkpoint_every`)"
                .into(),
        })
    }

    /// The state of the `index`-th stage in progress, copied to the host.
    fn current(
        index: usize,
        stage: &Stage,
        trainer: &Trainer,
        progress: &Progress,
        log: SavedLog,
    ) -> Result<Current> {
        Ok(Current {
            index,
            at: Snapshot {
                stage: stage.name.to_string(),
                channel: stage.channel.to_string(),
                model: ModelState::of(trainer.model()),
                curve: trainer.curve().map(|c| c.state()).transpose()?,
                log,
            },
            trainer: trainer.state(),
            progress: progress.clone(),
        })
    }

    fn write(&mut self, current: &Current) -> Result<()> {
        let path = self.file.path();
        let mut tensors = Tensors::default();
        let mut done_meta = Vec::new();
        for (i, f) in self.done.iter().enumerate() {
            done_meta.push(FinishedMeta {
                at: add_snapshot(&f.at, &format!("done{i}."), &mut tensors),
                report: f.report.clone(),
            });
        }
        let at = add_snapshot(&current.at, "current.", &mut tensors);
        if let Some((sum, count)) = &current.trainer.stats {
            tensors.f32("current.stats.sum", sum, [sum.len(), 1]);
            tensors.f32("current.stats.count", count, [count.len(), 1]);
        }
        let current_meta = CurrentMeta {
            index: current.index,
            at,
            trainer: current.trainer.clone(),
            stats: current.trainer.stats.is_some(),
            progress: current.progress.clone(),
        };
        let meta = vec![
            ("done", json_meta(path, "done", &done_meta)?),
            ("current", json_meta(path, "current", &Some(current_meta))?),
        ];
        self.file.write(FORMAT, &tensors, meta)?;
        self.written = Some((current.index, current.progress.iteration));
        Ok(())
    }
}

fn add_snapshot(at: &Snapshot, prefix: &str, out: &mut Tensors) -> SnapshotMeta {
    at.model.add_to(prefix, out);
    if let Some(c) = &at.curve {
        c.add_to(prefix, out);
    }
    SnapshotMeta {
        stage: at.stage.clone(),
        channel: at.channel.clone(),
        model: at.model.meta(),
        curve: at.curve.is_some(),
        log: at.log.clone(),
    }
}

fn read_snapshot(f: &TensorFile, prefix: &str, m: SnapshotMeta) -> Result<Snapshot> {
    let curve = if m.curve {
        Some(NetState::read(f, prefix)?)
    } else {
        None
    };
    Ok(Snapshot {
        stage: m.stage,
        channel: m.channel,
        model: ModelState::read(f, prefix, &m.model)?,
        curve,
        log: m.log,
    })
}
