//! The part of a checkpoint that every trained method shares: where the file is, when it is
//! written, the fingerprint it must match to be resumed from, its atomic write
//! ([`ResumeFile`]), and a network with its optimiser as Burn's exact records ([`NetState`]).
//! The Gaussian runs' [`super::Checkpoints`] and NAF's (`crate::methods::naf::resume`) build on them.

use crate::record::fingerprint::Fingerprint;
use crate::record::tensors::{TensorFile, Tensors, json_meta};
use crate::{Error, Result};
use burn::module::Module;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::store::ModuleRecord;
use burn::tensor::Bytes;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// The ChaCha8 word position saved as decimal text in `file`'s `field`: an integer within the
/// stream (2⁶⁴ blocks of 16 words, so below 2⁶⁸).
pub fn word_position(text: &str, file: &Path, field: &str) -> Result<u128> {
    let pos: u128 = text
        .parse()
        .map_err(|_| Error::field(file, field, format!("not an integer: `{text}`")))?;
    if pos >= 1 << 68 {
        return Err(Error::field(
            file,
            field,
            format!("{pos} lies beyond the random stream's 2^68 words"),
        ));
    }
    Ok(pos)
}

/// Refuse a saved running value that is not finite and ≥ 0 (times, loss sums), naming `field`
/// of `file`.
pub fn check_sum(value: f64, file: &Path, field: &str) -> Result<()> {
    if value.is_finite() && value >= 0.0 {
        return Ok(());
    }
    Err(Error::field(
        file,
        field,
        format!("{value} is not a finite value ≥ 0"),
    ))
}

/// Refuse a saved iteration counter beyond the `iterations` of the run resuming from it.
pub fn check_iteration(
    iteration: usize,
    iterations: usize,
    file: &Path,
    field: &str,
) -> Result<()> {
    if iteration <= iterations {
        return Ok(());
    }
    Err(Error::field(
        file,
        field,
        format!(
            "iteration {iteration} lies beyond this run's {iterations} iterations: resume with \
             the settings of the interrupted run"
        ),
    ))
}

/// A network and its optimiser, as Burn's records (exact): a curve model, or NAF's field.
#[derive(Clone, Debug, PartialEq)]
pub struct NetState {
    pub net: Vec<u8>,
    pub optim: Vec<u8>,
}

impl NetState {
    pub fn of<M: Module>(net: &M, optim: &ModuleOptimizer) -> Result<Self> {
        let fail = |e: burn::store::RecordError| {
            Error::invalid("network", format!("its state cannot be recorded: {e:?}"))
        };
        Ok(NetState {
            net: net
                .clone()
                .into_record()
                .into_bytes()
                .map_err(fail)?
                .to_vec(),
            optim: optim.into_bytes().map_err(fail)?.to_vec(),
        })
    }

    /// Load the saved records into `net` and `optim` (errors name `<prefix>net` / `optim` of
    /// `file`).
    pub fn restore<M: Module>(
        &self,
        net: &mut M,
        optim: &mut ModuleOptimizer,
        file: &Path,
        prefix: &str,
    ) -> Result<()> {
        let bad = |what: &str, e: burn::store::RecordError| {
            Error::field(
                file,
                format!("{prefix}{what}"),
                format!("unreadable record: {e:?}"),
            )
        };
        let field = |what: &str| format!("{prefix}{what}");
        let loaded = without_panics(file, &field("net"), || {
            let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(self.net.clone()))
                .map_err(|e| bad("net", e))?;
            net.clone()
                .try_load_record(record)
                .map_err(|e| bad("net", e))
        })?;
        *net = loaded;
        let mut audit = FiniteAudit::default();
        net.visit(&mut audit);
        if let Some(shape) = audit.non_finite {
            return Err(Error::field(
                file,
                format!("{prefix}net"),
                format!("a parameter tensor {shape:?} holds a value that is not finite"),
            ));
        }
        let saved = std::mem::replace(optim, AdamConfig::new().init());
        *optim = without_panics(file, &field("optim"), || {
            saved
                .from_bytes(Bytes::from_bytes_vec(self.optim.clone()))
                .map_err(|e| bad("optim", e))
        })?;
        Ok(())
    }

    /// Add the records to `out` as `<prefix>net` and `<prefix>optim`.
    pub(crate) fn add_to(&self, prefix: &str, out: &mut Tensors) {
        out.u8(format!("{prefix}net"), self.net.clone());
        out.u8(format!("{prefix}optim"), self.optim.clone());
    }

    /// The records [`NetState::add_to`] stored under `prefix`.
    pub(crate) fn read(f: &TensorFile, prefix: &str) -> Result<Self> {
        Ok(NetState {
            net: f.bytes(&format!("{prefix}net"))?,
            optim: f.bytes(&format!("{prefix}optim"))?,
        })
    }
}

/// `read`, with a panic inside it (Burn's record readers assert on some malformed records, e.g.
/// an optimiser tensor without a parameter id) turned into an error naming `field` of `file`.
/// The panic's default report is silenced meanwhile: the error says it.
fn without_panics<T>(file: &Path, field: &str, read: impl FnOnce() -> Result<T>) -> Result<T> {
    crate::error::catch_panics(read).unwrap_or_else(|why| {
        let why = why.unwrap_or_else(|| "malformed".into());
        Err(Error::field(
            file,
            field,
            format!("unreadable record: {why}"),
        ))
    })
}

/// Finds the first float parameter holding a NaN or an infinity.
#[derive(Default)]
struct FiniteAudit {
    non_finite: Option<Vec<usize>>,
}

impl burn::module::ModuleVisitor for FiniteAudit {
    fn visit_float<const D: usize>(
        &mut self,
        param: &burn::module::Param<burn::tensor::Tensor<D>>,
    ) {
        if self.non_finite.is_some() {
            return;
        }
        let t = param.val();
        let dims = t.dims().to_vec();
        let finite = t.into_data().iter::<f32>().all(f32::is_finite);
        if !finite {
            self.non_finite = Some(dims);
        }
    }
}

/// Where a run's state is saved, how often, and what a file must match to be resumed from:
/// the part of [`Checkpoints`] that NAF's (`crate::methods::naf::resume`) shares.
pub struct ResumeFile<'a> {
    path: PathBuf,
    every: usize,
    fingerprint: Fingerprint,
    stop: Option<&'a AtomicBool>,
}

impl<'a> ResumeFile<'a> {
    /// Save to `path` every `every` iterations (0: only when stopped or diverging) and when
    /// `stop` is set; refuse files whose fingerprint differs from `fingerprint`.
    pub fn new(
        path: PathBuf,
        every: usize,
        fingerprint: Fingerprint,
        stop: Option<&'a AtomicBool>,
    ) -> Self {
        ResumeFile {
            path,
            every,
            fingerprint,
            stop,
        }
    }

    /// Where the checkpoint is written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether the run was asked to stop.
    pub fn stop_requested(&self) -> bool {
        self.stop.is_some_and(|s| s.load(Ordering::Relaxed))
    }

    /// Whether iteration `it` ends with a scheduled checkpoint.
    pub fn due(&self, it: usize) -> bool {
        self.every > 0 && it.is_multiple_of(self.every)
    }

    /// The file to resume from: it must exist, be of `format` and carry this run's fingerprint.
    pub(crate) fn open(&self, format: &str) -> Result<TensorFile<'_>> {
        let path = &self.path;
        if !path.is_file() {
            return Err(Error::field(
                path,
                ".",
                "no checkpoint to resume from (a run writes one when interrupted, diverging, or \
                 every `checkpoint_every` iterations)",
            ));
        }
        let f = TensorFile::open(path, format)?;
        let saved: Fingerprint = f.json("fingerprint")?;
        if let Some(why) = saved.mismatch(&self.fingerprint) {
            return Err(Error::field(
                path,
                "metadata.fingerprint",
                format!("this checkpoint does not belong to this run: {why}"),
            ));
        }
        Ok(f)
    }

    /// Write `tensors` and the JSON metadata `meta` (`format` and `fingerprint` added) beside
    /// the file and rename it over the previous one: a crash while writing keeps the last
    /// complete checkpoint.
    pub(crate) fn write(
        &self,
        format: &str,
        tensors: &Tensors,
        meta: Vec<(&str, String)>,
    ) -> Result<()> {
        let path = &self.path;
        let fingerprint = json_meta(path, "fingerprint", &self.fingerprint)?;
        let meta: HashMap<String, String> =
            [("format", format.to_string()), ("fingerprint", fingerprint)]
                .into_iter()
                .chain(meta)
                .map(|(k, v)| (k.to_string(), v))
                .collect();
        let tmp = path.with_extension("partial");
        tensors.write(&tmp, meta)?;
        std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
    }
}
