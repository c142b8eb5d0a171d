//! What every method's run is given and what it sees: its options ([`RunOptions`], with the
//! checkpointing of trained methods), and the scene checked and split into the observed and the
//! held-out channels ([`Setup`]).

use crate::evaluate::{CurveScoring, Evaluation};
use crate::record::RunDir;
use crate::record::fingerprint::Fingerprint;
use crate::record::resume::ResumeFile;
use crate::{Error, MethodConfig, Result};
use burn::tensor::Device;
use prism_domain::observe::{Level, Observer};
use prism_domain::projector::check_fov;
use prism_domain::scene::Scene;
use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

/// How a run runs: where, from what, and who hears of its progress.
pub struct RunOptions<'a> {
    /// The device of the Gaussian methods (classic methods run on the CPU).
    pub device: Device,
    /// `4dsg` / `4dsg-stage1`: continue from this stage-1 checkpoint (a file, or a run directory
    /// holding one) instead of training stage 1.
    pub from_geometry: Option<&'a Path>,
    pub observer: &'a dyn Observer,
    /// How the volumes are scored (`metrics.json`, `holdout.json`).
    pub evaluation: &'a Evaluation,
    /// Gaussian methods and NAF: where the run saves its state, and whether it continues from
    /// it.
    pub checkpoint: Option<Checkpointing<'a>>,
}

/// A Gaussian or NAF run's checkpoint (`crate::gaussians::train::checkpoints`, `crate::methods::naf::resume`): written to `path` when `stop` is set
/// (the run then ends with [`Error::Interrupted`]), when a stage diverges and every
/// `checkpoint_every` iterations; removed when the run is published.
pub struct Checkpointing<'a> {
    pub path: PathBuf,
    /// Continue the run saved in `path`.
    pub resume: bool,
    pub stop: Option<&'a AtomicBool>,
}

impl<'a> Checkpointing<'a> {
    /// Where a run published at `out` keeps its state by default: beside it, as
    /// `<out>.resume.safetensors` (`prism recon` and the Python package alike).
    pub fn default_path(out: &Path) -> Result<PathBuf> {
        let Some(name) = out.file_name() else {
            return Err(Error::invalid(
                "output",
                format!("`{}`: name the output directory", out.display()),
            ));
        };
        let mut file = name.to_os_string();
        file.push(".resume.safetensors");
        Ok(out.with_file_name(file))
    }

    /// The resume file of a run with `fingerprint`, saved every `every` iterations.
    pub fn file(&self, every: usize, fingerprint: Fingerprint) -> ResumeFile<'a> {
        ResumeFile::new(self.path.clone(), every, fingerprint, self.stop)
    }
}

impl RunOptions<'_> {
    /// Whether these options suit `config` (called by [`run`]; callers may call it before they
    /// create the run directory).
    pub fn check(&self, config: &MethodConfig) -> Result<()> {
        let method = config.method();
        if self.checkpoint.as_ref().is_some_and(|c| c.resume) && !method.trains() {
            return Err(Error::invalid(
                "--resume",
                format!(
                    "`{}` saves no training state: --resume applies to the Gaussian methods \
                     and NAF",
                    method.name()
                ),
            ));
        }
        if self.from_geometry.is_some() && !method.has_shared_geometry() {
            return Err(Error::invalid(
                "--from-geometry",
                format!(
                    "`{}` has no shared geometry: --from-geometry applies to `4dsg` and \
                     `4dsg-stage1`",
                    method.name()
                ),
            ));
        }
        Ok(())
    }
}

/// The scene as a run sees it: checked, its held-out channels removed, the training views of
/// each remaining channel.
pub(crate) struct Setup<'a> {
    /// The full scene (held-out channels included, for scoring predictions).
    pub full: &'a Scene,
    /// The scene without held-out channels (the full scene, borrowed, when none is held out).
    pub observed: Cow<'a, Scene>,
    /// Indices (in `full`) of the held-out channels.
    pub held: Vec<usize>,
    /// Training views of each observed channel.
    pub views: Vec<Vec<usize>>,
    /// Fraction of the volume outside the field of view (for the metrics).
    pub unseen: f64,
    /// How training curves are scored: over the whole grid, or inside the evaluation's mask.
    pub scoring: CurveScoring,
}

impl<'a> Setup<'a> {
    /// Check `scene` (and that its channels' volumes get distinct files), warn about voxels no
    /// ray sees, set the `held` channels aside, and score training curves as `options`'
    /// evaluation takes the final metrics (inside its object mask, when it has one).
    pub fn new(scene: &'a Scene, held: Vec<usize>, options: &RunOptions) -> Result<Self> {
        let observer = options.observer;
        scene.validate()?;
        RunDir::check_labels(scene)?;
        let unseen = check_fov(&scene.geometry).map_err(|e| Error::from(e).under("geometry"))?;
        if unseen > 0.0 {
            observer.note(
                Level::Warning,
                &format!(
                    "{:.1} % of the volume grid's voxels are seen by no ray; they stay at their \
                     initial value",
                    100.0 * unseen
                ),
            );
        }
        let observed = if held.is_empty() {
            Cow::Borrowed(scene)
        } else {
            Cow::Owned(scene.without_channels(&held))
        };
        let views = observed.channel_training_views()?;
        Ok(Setup {
            full: scene,
            observed,
            held,
            views,
            unseen,
            scoring: CurveScoring::of(options.evaluation, scene)?,
        })
    }
}

/// One volume per channel (mm⁻¹, `[z][y][x]`).
pub type Volumes = Vec<ndarray::Array3<f32>>;
