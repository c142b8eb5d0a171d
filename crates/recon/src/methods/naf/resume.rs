//! Interrupting and resuming a NAF run: the finished channels' volumes and the channel in
//! progress in one file.
//!
//! A NAF run fits its channels one after another. With [`NafCheckpoints`] it saves its state
//! every `checkpoint_every` iterations and when asked to stop (SIGINT / SIGTERM in the `prism`
//! binary; the current step finishes first): the volumes of the channels already fitted, the
//! field and Adam state of the channel in progress (Burn's records, exact), its loop state
//! ([`LoopState`]: random stream position, view order, running loss sums) and the log so far.
//! A resumed run takes the finished volumes as they are and continues the channel in progress
//! from the next iteration; on the same device the result equals the uninterrupted run's bit for
//! bit. A file from another scene or other settings is refused, naming what differs
//! ([`crate::record::fingerprint`]). A diverging NAF step has already made the field's parameters
//! non-finite (its output is a bounded sigmoid), so the error names the last file written.
//!
//! Format: safetensors `prism-naf-resume/1`. Tensors: `done<c>` (f32 `[nz·ny, nx]`, channel c's
//! volume, mm⁻¹), `current.net` / `current.optim` (u8 records). Metadata (JSON): `format`,
//! `fingerprint`, `done` (the number of finished channels), `current` ([`LoopState`] or null),
//! `log`.

use crate::gaussians::train::checkpoints::{NetState, ResumeFile};
use crate::record::log::SavedLog;
use crate::record::resume::{check_iteration, check_sum, word_position};
use crate::record::tensors::{Tensors, json_meta};
use crate::{Error, Result};
use burn::optim::ModuleOptimizer;
use ndarray::Array3;
use prism_field::NeuralField;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

const FORMAT: &str = "prism-naf-resume/1";

/// The loop of the channel in progress after `iteration` iterations.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoopState {
    /// 0-based channel index and label.
    pub channel: usize,
    pub label: String,
    /// Iterations done.
    pub iteration: usize,
    /// The batch sampler's ChaCha8 word position (decimal: a u128), before the next
    /// iteration's draws.
    pub rng_word_pos: String,
    /// The current epoch's view order.
    pub order: Vec<usize>,
    /// Loss sum and count since the last log record.
    pub loss_sum: f64,
    pub loss_n: usize,
}

impl LoopState {
    /// Refuse a loop that a run of `iterations` iterations over `views` views cannot have
    /// saved (`file` names it in errors).
    pub fn check(&self, iterations: usize, views: usize, file: &Path) -> Result<()> {
        let field = |f: &str| format!("metadata.current.{f}");
        check_iteration(self.iteration, iterations, file, &field("iteration"))?;
        // Within an epoch the order is the epoch's permutation of the views (refilled at the
        // epoch's first iteration, so any saved order is then unused).
        if !self.iteration.is_multiple_of(views) {
            let why = if self.order.len() != views {
                Some(format!("{} entries", self.order.len()))
            } else {
                prism_domain::indices::distinct_below(&self.order, views)
                    .err()
                    .map(|fault| format!("view {fault}"))
            };
            if let Some(why) = why {
                return Err(Error::field(
                    file,
                    field("order"),
                    format!("not an order of the {views} training views: {why}"),
                ));
            }
        }
        check_sum(self.loss_sum, file, &field("loss_sum"))?;
        if self.loss_n > self.iteration {
            return Err(Error::field(
                file,
                field("loss_n"),
                format!(
                    "{} losses summed, {} iterations done",
                    self.loss_n, self.iteration
                ),
            ));
        }
        Ok(())
    }

    /// The sampler positioned where this state left it (seeded with `seed`).
    pub fn rng(&self, seed: u64, file: &Path) -> Result<ChaCha8Rng> {
        let pos = word_position(&self.rng_word_pos, file, "metadata.current.rng_word_pos")?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_word_pos(pos);
        Ok(rng)
    }
}

/// The channel in progress: its field and optimiser records and its loop.
#[derive(Clone, Debug)]
pub struct FieldProgress {
    net: NetState,
    pub state: LoopState,
}

impl FieldProgress {
    /// The state of `field` and `optim` with the loop `state`.
    pub fn of(field: &NeuralField, optim: &ModuleOptimizer, state: LoopState) -> Result<Self> {
        Ok(FieldProgress {
            net: NetState::of(field, optim)?,
            state,
        })
    }

    /// Load the saved field and optimiser into `field` and `optim`.
    pub fn restore(
        &self,
        field: &mut NeuralField,
        optim: &mut ModuleOptimizer,
        file: &Path,
    ) -> Result<()> {
        self.net.restore(field, optim, file, "current.")
    }
}

/// What a NAF checkpoint holds.
pub struct Saved {
    /// The finished channels' volumes, in channel order.
    pub finished: Vec<Array3<f32>>,
    pub current: Option<FieldProgress>,
    pub log: SavedLog,
}

/// Where a NAF run saves its state and when (see the module docs).
pub struct NafCheckpoints<'a> {
    file: ResumeFile<'a>,
    /// (channel, iteration) of the last file written.
    written: Option<(usize, usize)>,
    /// The run continues the state read from the file.
    resumed: bool,
}

impl<'a> NafCheckpoints<'a> {
    /// Checkpoints saved to and resumed from `file`.
    pub fn new(file: ResumeFile<'a>) -> Self {
        NafCheckpoints {
            file,
            written: None,
            resumed: false,
        }
    }

    /// Where, when and against what the checkpoints are saved.
    pub fn file(&self) -> &ResumeFile<'a> {
        &self.file
    }

    /// The state saved in the file, for a run of `channels` channels on a `[nz, ny, nx]` grid.
    pub fn read(&mut self, channels: usize, shape: [usize; 3]) -> Result<Saved> {
        self.resumed = true;
        let f = self.file.open(FORMAT)?;
        let path = f.path();
        let done: usize = f.json("done")?;
        let current: Option<LoopState> = f.json("current")?;
        let log: SavedLog = f.json("log")?;
        let next = done + usize::from(current.is_some());
        if next > channels || (current.is_none() && done < channels) {
            return Err(Error::field(
                path,
                "metadata.done",
                format!(
                    "the checkpoint holds {done} finished channels{}, this run fits {channels}",
                    if current.is_some() {
                        " and one in progress"
                    } else {
                        ""
                    }
                ),
            ));
        }
        let [nz, ny, nx] = shape;
        let finished = (0..done)
            .map(|c| {
                let name = format!("done{c}");
                let values = f.rows(&name, nx)?;
                Array3::from_shape_vec((nz, ny, nx), values).map_err(|_| {
                    Error::field(path, &name, format!("expected {nz}×{ny} rows of {nx}"))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let current = match current {
            Some(state) if state.channel != done => {
                return Err(Error::field(
                    path,
                    "metadata.current.channel",
                    format!("channel {} follows {done} finished ones", state.channel),
                ));
            }
            Some(state) => Some(FieldProgress {
                net: NetState::read(&f, "current.")?,
                state,
            }),
            None => None,
        };
        Ok(Saved {
            finished,
            current,
            log,
        })
    }

    /// Write the finished volumes, the channel in progress and the log, atomically.
    pub fn save(
        &mut self,
        finished: &[Array3<f32>],
        current: &FieldProgress,
        log: &SavedLog,
    ) -> Result<()> {
        let path = self.file.path();
        let mut tensors = Tensors::default();
        for (c, v) in finished.iter().enumerate() {
            let (nz, ny, nx) = v.dim();
            let values: Vec<f32> = v.iter().copied().collect();
            tensors.f32(format!("done{c}"), &values, [nz * ny, nx]);
        }
        current.net.add_to("current.", &mut tensors);
        let meta = vec![
            ("done", json_meta(path, "done", &finished.len())?),
            (
                "current",
                json_meta(path, "current", &Some(&current.state))?,
            ),
            ("log", json_meta(path, "log", log)?),
        ];
        self.file.write(FORMAT, &tensors, meta)?;
        self.written = Some((current.state.channel, current.state.iteration));
        Ok(())
    }

    /// For a diverging step's error: where the last good state is, if one was written.
    pub fn last_written(&self) -> String {
        match self.written {
            Some((c, it)) => format!(
                "; the last saved state (channel {c}, iteration {it}) is in `{}`",
                self.file.path().display()
            ),
            None if self.resumed => format!(
                "; the run resumed from `{}` (no state was saved since)",
                self.file.path().display()
            ),
            None => "; no earlier state was saved (set `checkpoint_every`)".into(),
        }
    }
}
