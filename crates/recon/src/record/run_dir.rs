//! A run directory: every file a run writes, written beside the target and published at the end
//! as a whole (`prism_domain::staged`).
//!
//! A run owns the files it writes and lists them in its manifest (`run.json`). A target that is
//! not empty is refused unless `force` is given; then the previous run's own files (from its
//! manifest) and the files this run writes again are replaced, and anything else in the
//! directory (a user's notes, a query's output) is kept. So nothing stale of an earlier run
//! survives a rerun, and a failed run leaves the previous results as they were.
//!
//! Files, all in the directory itself:
//!
//! | file | what |
//! |---|---|
//! | `config.resolved.yaml` | the configuration with every default filled in |
//! | `<label>.npy` | one volume per channel, μ in mm⁻¹, `[z][y][x]` float32 ([`RunDir::volume_file`]) |
//! | `metrics.json` | scores against the scene's references (`crate::evaluate::Metrics`) |
//! | `log.jsonl` | Gaussian methods: error and loss against time (`crate::record::log`) |
//! | `train.json` | Gaussian methods: per-stage time split and summary |
//! | `gaussians[-<label>].safetensors`, `.ply` | Gaussian methods: the trained model(s) |
//! | `geometry.safetensors` | 4D-SG: stage 1's checkpoint (`crate::methods::fourdsg::stage1::checkpoint`) |
//! | `holdout.json` | 4D-SG with held-out channels: their predictions' scores |
//! | `run.json` | the manifest: the files above that this run wrote |

use crate::{Error, Result};
use ndarray::Array3;
use prism_domain::scene::Scene;
use prism_domain::staged::{Staged, entries};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::ffi::OsString;
use std::fs;
use std::path::{Path, PathBuf};

/// The manifest of a published run directory (`run.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// `prism-run/1`.
    pub format: String,
    /// The entries this run wrote (files, and the run directories nested in it), sorted.
    pub files: Vec<String>,
}

const MANIFEST_FORMAT: &str = "prism-run/1";

/// A run directory being written (see the module docs).
#[derive(Debug)]
pub struct RunDir {
    target: PathBuf,
    /// Where the files are written now.
    root: PathBuf,
    /// The staging of a top-level run; `None` for a run nested in another, which is published
    /// with it.
    staged: Option<Staged>,
    force: bool,
    files: BTreeSet<String>,
}

impl RunDir {
    pub const CONFIG: &str = "config.resolved.yaml";
    pub const METRICS: &str = "metrics.json";
    pub const LOG: &str = "log.jsonl";
    pub const TRAIN: &str = "train.json";
    pub const HOLDOUT: &str = "holdout.json";
    /// An ablation's table (`prism ablate`), beside one run directory per variant.
    pub const ABLATION: &str = "ablation.json";
    /// 4D-SG's stage-1 checkpoint.
    pub const GEOMETRY: &str = "geometry.safetensors";
    /// The trained model of a spectral run (one model for every channel).
    pub const MODEL: &str = "gaussians.safetensors";
    pub const MANIFEST: &str = "run.json";

    /// Start a run that will be published to `target`. A `target` that exists and is not empty
    /// is refused unless `force` (see the module docs).
    pub fn create(target: &Path, force: bool) -> Result<RunDir> {
        if target.is_dir() && !entries(target)?.is_empty() && !force {
            return Err(Error::invalid(
                "output",
                format!(
                    "`{}` is not empty; pass --force to replace the run files in it (files an \
                     earlier run did not write are kept)",
                    target.display()
                ),
            ));
        }
        let staged = Staged::create(target)?;
        Ok(RunDir {
            target: target.to_path_buf(),
            root: staged.path().to_path_buf(),
            staged: Some(staged),
            force,
            files: BTreeSet::new(),
        })
    }

    /// A run directory `name` inside this one, published with it (an ablation's variants).
    pub fn child(&mut self, name: &str) -> Result<RunDir> {
        let root = self.file(name);
        fs::create_dir(&root).map_err(|e| Error::io(&root, e))?;
        Ok(RunDir {
            target: self.target.join(name),
            root,
            staged: None,
            force: self.force,
            files: BTreeSet::new(),
        })
    }

    /// Where the files are being written.
    pub fn path(&self) -> &Path {
        &self.root
    }

    /// Where the run will be (or was) published.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// The path of the run's entry `name` (recorded in the manifest).
    pub fn file(&mut self, name: &str) -> PathBuf {
        self.files.insert(name.to_string());
        self.root.join(name)
    }

    /// A channel label as a file-name stem: every character but ASCII letters, digits, `-`,
    /// `_` and `.` replaced by `_`.
    pub fn stem(label: &str) -> String {
        label
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect()
    }

    /// The file name of a channel's volume: `<stem>.npy` ([`RunDir::stem`]).
    pub fn volume_file(label: &str) -> String {
        format!("{}.npy", Self::stem(label))
    }

    /// Refuse a scene two of whose channels would write the same volume file.
    pub fn check_labels(scene: &Scene) -> Result<()> {
        let mut seen: Vec<(String, &str)> = Vec::new();
        for ch in &scene.channels {
            let f = Self::volume_file(&ch.label);
            if let Some((_, other)) = seen.iter().find(|(g, _)| *g == f) {
                return Err(Error::invalid(
                    "channels",
                    format!(
                        "channels `{other}` and `{}` would both be written to {f}; give them \
                         labels that differ in letters, digits, `-`, `_` or `.`",
                        ch.label
                    ),
                ));
            }
            seen.push((f, &ch.label));
        }
        Ok(())
    }

    /// Write a channel's volume (`[z][y][x]`, mm⁻¹) as `<label>.npy`.
    pub fn write_volume(&mut self, label: &str, vol: &Array3<f32>) -> Result<PathBuf> {
        let path = self.file(&Self::volume_file(label));
        ndarray_npy::write_npy(&path, vol)
            .map_err(|e| Error::field(&path, "data", format!("writing the volume failed: {e}")))?;
        Ok(path)
    }

    /// Write `value` as pretty JSON to the entry `name`.
    pub fn write_json<T: Serialize>(&mut self, name: &str, value: &T) -> Result<()> {
        let path = self.file(name);
        fs::write(&path, Self::json(&path, value)?).map_err(|e| Error::io(&path, e))
    }

    /// Replace the JSON file `path` of a published run (`metrics.json` scored again, a suite
    /// cell's record) atomically, in [`RunDir::write_json`]'s format.
    pub fn replace_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
        Ok(prism_domain::staged::replace_file(
            path,
            Self::json(path, value)?.as_bytes(),
        )?)
    }

    /// `value` as pretty JSON with a final newline; errors name `path`.
    fn json<T: Serialize>(path: &Path, value: &T) -> Result<String> {
        let json = serde_json::to_string_pretty(value)
            .map_err(|e| Error::field(path, ".", e.to_string()))?;
        Ok(json + "\n")
    }

    /// Read a JSON file a run wrote (`metrics.json`, `ablation.json`, …); errors name the file.
    pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
        let text = fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        serde_json::from_str(&text).map_err(|e| Error::field(path, ".", e.to_string()))
    }

    /// Write `text` to the entry `name`.
    pub fn write_text(&mut self, name: &str, text: &str) -> Result<()> {
        let path = self.file(name);
        fs::write(&path, text).map_err(|e| Error::io(&path, e))
    }

    /// Write the manifest and, for a top-level run, publish the directory; returns where it is.
    pub fn publish(mut self) -> Result<PathBuf> {
        let manifest = self.file(Self::MANIFEST);
        let m = Manifest {
            format: MANIFEST_FORMAT.into(),
            files: self.files.iter().cloned().collect(),
        };
        let json = serde_json::to_string_pretty(&m)
            .map_err(|e| Error::field(&manifest, ".", e.to_string()))?;
        fs::write(&manifest, json + "\n").map_err(|e| Error::io(&manifest, e))?;
        if let Some(staged) = self.staged.take() {
            let (force, ours) = (self.force, self.files.clone());
            staged.publish(|old| {
                if !force {
                    return Ok(BTreeSet::new());
                }
                let mut owned: BTreeSet<OsString> = ours.iter().map(OsString::from).collect();
                owned.extend(Self::manifest(old)?.files.into_iter().map(OsString::from));
                Ok(owned)
            })?;
        }
        Ok(self.target)
    }

    /// The model file of the spectral run published in `dir` (what `prism query` reads).
    pub fn spectral_model(dir: &Path) -> Result<PathBuf> {
        let path = dir.join(Self::MODEL);
        if !path.exists() {
            return Err(Error::invalid(
                "run_dir",
                format!(
                    "{} has no {}: queries need a spectral run (method 4dsg or 4dsg-stage1); \
                     r2gs runs keep one independent model per channel",
                    dir.display(),
                    Self::MODEL
                ),
            ));
        }
        Ok(path)
    }

    /// The manifest of a published run directory (empty when it has none).
    pub fn manifest(dir: &Path) -> prism_domain::Result<Manifest> {
        use prism_domain::Error;
        let path = dir.join(Self::MANIFEST);
        if !path.exists() {
            return Ok(Manifest {
                format: MANIFEST_FORMAT.into(),
                files: Vec::new(),
            });
        }
        let text = fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let m: Manifest =
            serde_json::from_str(&text).map_err(|e| Error::field(&path, ".", e.to_string()))?;
        if m.format != MANIFEST_FORMAT {
            return Err(Error::field(
                &path,
                "format",
                format!("expected `{MANIFEST_FORMAT}`, got `{}`", m.format),
            ));
        }
        if let Some(bad) = m.files.iter().find(|f| !is_entry_name(f)) {
            return Err(Error::field(
                &path,
                "files",
                format!("`{bad}` is not a file name inside the run directory"),
            ));
        }
        Ok(m)
    }
}

/// A bare name inside a directory (no separators, not `.` or `..`).
fn is_entry_name(name: &str) -> bool {
    let p = Path::new(name);
    p.components().count() == 1
        && matches!(p.components().next(), Some(std::path::Component::Normal(_)))
}
