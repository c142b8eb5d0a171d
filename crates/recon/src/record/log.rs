//! The run log: one JSON object per line in `log.jsonl`, written as training goes, so error vs
//! run time can be plotted for any method.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Loss terms (mean over the iterations since the previous record).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LossTerms {
    pub total: f64,
    pub l1: f64,
    pub dssim: f64,
    pub tv: f64,
    /// Stage 2's curve smoothness L_curve (0 elsewhere).
    pub curve: f64,
}

impl LossTerms {
    /// Add `o` term by term (a running sum).
    pub fn add(&mut self, o: &LossTerms) {
        self.total += o.total;
        self.l1 += o.l1;
        self.dssim += o.dssim;
        self.tv += o.tv;
        self.curve += o.curve;
    }

    /// The mean of a running sum over `k` terms (the sum itself when `k` is 0).
    pub fn mean_of(&self, k: usize) -> LossTerms {
        let kf = k.max(1) as f64;
        LossTerms {
            total: self.total / kf,
            l1: self.l1 / kf,
            dssim: self.dssim / kf,
            tv: self.tv / kf,
            curve: self.curve / kf,
        }
    }
}

/// One line of `log.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LogRecord {
    /// Training stage (`r2gs`, `geometry`, `densities`, …).
    pub stage: String,
    /// What the stage fits: a channel label, `structural`, or `all`.
    pub channel: String,
    /// Iteration within the stage (1-based).
    pub iter: usize,
    /// Seconds since the run started, evaluation included.
    pub wall_s: f64,
    /// Seconds since the run started, evaluation excluded.
    pub train_s: f64,
    pub loss: LossTerms,
    /// Gaussians in the model (absent for methods without Gaussians).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub n_gaussians: Option<usize>,
    /// Mean 3-D PSNR (dB) / SSIM over the stage's channels, when references exist.
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
}

/// A [`RunLog`]'s state: its clocks and the records written so far (JSON lines).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SavedLog {
    pub wall_s: f64,
    pub eval_s: f64,
    pub lines: Vec<String>,
}

/// The run clock and the open log file.
pub struct RunLog {
    start: Instant,
    /// Wall seconds already on the clock at `start` (a forked log continues its parent's time).
    base_wall_s: f64,
    /// The wall clock's reading when [`RunLog::stop`] froze it.
    stopped: Option<f64>,
    eval_s: f64,
    out: Option<(PathBuf, BufWriter<File>)>,
    /// Every line written so far (for [`RunLog::fork`]).
    lines: Vec<String>,
}

impl RunLog {
    /// Start the clock and create the log file `path` (truncating an old one).
    pub fn create(path: &Path) -> Result<Self> {
        let f = File::create(path).map_err(|e| Error::io(path, e))?;
        Ok(RunLog {
            start: Instant::now(),
            base_wall_s: 0.0,
            stopped: None,
            eval_s: 0.0,
            out: Some((path.to_path_buf(), BufWriter::new(f))),
            lines: Vec::new(),
        })
    }

    /// A clock without a file (tests, benchmarks).
    pub fn in_memory() -> Self {
        RunLog {
            start: Instant::now(),
            base_wall_s: 0.0,
            stopped: None,
            eval_s: 0.0,
            out: None,
            lines: Vec::new(),
        }
    }

    /// Freeze the clocks at their current readings (the end of a shared stage): later
    /// [`RunLog::fork`]s all continue from here, however long after they are made.
    pub fn stop(&mut self) {
        self.stopped = Some(self.wall_s());
    }

    /// A log in the file `path` that continues this one: its file starts with this log's
    /// records and its clocks count on from this log's times (frozen by [`RunLog::stop`], else
    /// current). A stage-2 variant trained from a shared stage-1 geometry thus reports the whole
    /// run, geometry included, and not the other variants' time.
    pub fn fork(&self, path: &Path) -> Result<RunLog> {
        RunLog::resume(path, &self.saved())
    }

    /// The log's state, to continue it later ([`RunLog::resume`]).
    pub fn saved(&self) -> SavedLog {
        SavedLog {
            wall_s: self.wall_s(),
            eval_s: self.eval_s,
            lines: self.lines.clone(),
        }
    }

    /// A log in the file `path` that continues `saved`: its records first, its clocks running
    /// on.
    pub fn resume(path: &Path, saved: &SavedLog) -> Result<RunLog> {
        let mut log = RunLog::create(path)?;
        log.base_wall_s = saved.wall_s;
        log.eval_s = saved.eval_s;
        for line in &saved.lines {
            log.write_line(line.clone())?;
        }
        Ok(log)
    }

    /// Go back to `saved` (a checkpoint's log): its records replace this log's, in memory and
    /// in its file, and its clocks run on from `saved`'s.
    pub fn restore(&mut self, saved: &SavedLog) -> Result<()> {
        *self = match &self.out {
            Some((path, _)) => RunLog::resume(&path.clone(), saved)?,
            None => RunLog {
                base_wall_s: saved.wall_s,
                eval_s: saved.eval_s,
                lines: saved.lines.clone(),
                ..RunLog::in_memory()
            },
        };
        Ok(())
    }

    pub fn wall_s(&self) -> f64 {
        self.stopped
            .unwrap_or_else(|| self.base_wall_s + self.start.elapsed().as_secs_f64())
    }

    pub fn train_s(&self) -> f64 {
        self.wall_s() - self.eval_s
    }

    /// Run `f` as evaluation: its time is excluded from `train_s`.
    pub fn evaluating<T>(&mut self, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = f();
        self.eval_s += t.elapsed().as_secs_f64();
        out
    }

    pub fn write(&mut self, record: &LogRecord) -> Result<()> {
        let line = serde_json::to_string(record).map_err(|e| {
            let path = self
                .out
                .as_ref()
                .map(|(p, _)| p.clone())
                .unwrap_or_default();
            Error::field(path, ".", e.to_string())
        })?;
        self.write_line(line)
    }

    fn write_line(&mut self, line: String) -> Result<()> {
        if let Some((path, w)) = &mut self.out {
            writeln!(w, "{line}")
                .and_then(|_| w.flush())
                .map_err(|e| Error::io(path.as_path(), e))?;
        }
        self.lines.push(line);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// Forks of a stopped log start from the stop time (not from when they are made) and carry
    /// its records.
    #[test]
    fn forks_of_a_stopped_log_continue_from_the_stop() {
        let dir = tempfile::tempdir().unwrap();
        let mut root = RunLog::create(&dir.path().join("log.jsonl")).unwrap();
        let record = LogRecord {
            stage: "geometry".into(),
            channel: "structural".into(),
            iter: 1,
            wall_s: 0.0,
            train_s: 0.0,
            loss: LossTerms::default(),
            n_gaussians: Some(3),
            psnr: None,
            ssim: None,
        };
        root.write(&record).unwrap();
        root.stop();
        let at_stop = root.wall_s();
        std::thread::sleep(Duration::from_millis(300));
        assert_eq!(root.wall_s(), at_stop, "a stopped clock does not run");
        let sub = dir.path().join("variant");
        std::fs::create_dir(&sub).unwrap();
        let fork = root.fork(&sub.join("log.jsonl")).unwrap();
        // The 300 ms spent before forking are not on the fork's clock.
        let t = fork.wall_s();
        assert!(t >= at_stop && t < at_stop + 0.2, "{t} vs {at_stop}");
        let text = std::fs::read_to_string(sub.join("log.jsonl")).unwrap();
        assert_eq!(text.lines().count(), 1);
        assert!(text.contains("\"geometry\""));
    }
}
