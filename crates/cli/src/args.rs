//! Arguments shared by several subcommands: where a run goes, how it is scored, where a Gaussian
//! method runs, and `--set` overrides of a config.

use crate::progress::Bars;
use anyhow::bail;
use prism_domain::yaml::Overrides;
use prism_recon::MethodConfig;
use prism_recon::device::{DeviceChoice, cpu_device};
use prism_recon::evaluate::lpips::Lpips;
use prism_recon::evaluate::{Evaluation, Protocol, SliceAxes};
use prism_recon::record::RunDir;
use prism_recon::setup::Checkpointing;
use prism_recon::setup::RunOptions;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// `--set key.path=value` overrides of a YAML config.
#[derive(clap::Args)]
pub struct SetArgs {
    /// Override a config value: a dotted key (a number indexes a list) and a YAML value, e.g.
    /// `--set geometry.views=13 --set channels.0.kev=50`; repeatable, later ones win; recorded in
    /// the output (scene.yaml provenance, a run's config.resolved.yaml).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

impl SetArgs {
    pub fn overrides(&self) -> anyhow::Result<Overrides> {
        Ok(Overrides::parse(&self.set)?)
    }
}

/// How the volumes are scored (`docs/metrics.md`).
#[derive(clap::Args)]
pub struct EvalArgs {
    /// Evaluation grid: `native` (the reconstruction's own) or an edge length `n` (both volumes
    /// resampled trilinearly to n³; the paper evaluates on 256³).
    #[arg(long = "eval-grid", value_name = "native|N", default_value = "native")]
    pub grid: String,
    /// Slices of the slice-averaged metrics: `axial` (z) or `all` (z, y and x).
    #[arg(long = "eval-slices", value_enum, default_value = "axial")]
    pub slices: SlicesArg,
    /// LPIPS weights (safetensors made by scripts/lpips_weights.py); without them the LPIPS
    /// fields of metrics.json are null.
    #[arg(long = "lpips-weights", value_name = "FILE")]
    pub lpips_weights: Option<PathBuf>,
    /// Score inside the object only: the mask's settings as YAML, e.g.
    /// `--eval-roi '{threshold: 0.1, erode_mm: 1.0}'` (the object), `'{region: field_of_view}'` (the
    /// voxels every view sees); fields in docs/metrics.md, `{}` the defaults.
    #[arg(long = "eval-roi", value_name = "YAML")]
    pub roi: Option<String>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum SlicesArg {
    Axial,
    All,
}

impl EvalArgs {
    /// The evaluation these arguments ask for (LPIPS on the CPU).
    pub fn evaluation(&self) -> anyhow::Result<Evaluation> {
        let grid = match self.grid.as_str() {
            "native" => None,
            n => match n.parse::<usize>() {
                Ok(n) => {
                    Protocol::check_grid(Some(n), "--eval-grid")?;
                    Some(n)
                }
                _ => anyhow::bail!("--eval-grid: expected `native` or an edge length, got `{n}`"),
            },
        };
        let slices = match self.slices {
            SlicesArg::Axial => SliceAxes::Axial,
            SlicesArg::All => SliceAxes::All,
        };
        let roi = match &self.roi {
            Some(text) => {
                let spec: prism_domain::metrics::RoiSpec = prism_domain::yaml::parse_with(
                    text,
                    Path::new("--eval-roi"),
                    &Overrides::default(),
                )?;
                spec.validate().map_err(|e| e.under("--eval-roi"))?;
                Some(spec)
            }
            None => None,
        };
        let lpips = match &self.lpips_weights {
            Some(p) => Some(Arc::new((Lpips::load(p, &cpu_device())?, p.clone()))),
            None => None,
        };
        Ok(Evaluation {
            protocol: Protocol { grid, slices, roi },
            lpips,
        })
    }
}

/// Where a Gaussian method runs and what it starts from.
#[derive(clap::Args)]
pub struct GaussianArgs {
    /// Compute device of a Gaussian or NAF method (overrides the config's `device`): `cpu`, or `wgpu`
    /// in a prism built with `--features wgpu` (a GPU, or Mesa's lavapipe without one).
    #[arg(long = "device")]
    pub device: Option<DeviceArg>,
    /// `4dsg` / `4dsg-stage1` only: skip stage 1 and continue from its checkpoint
    /// (`geometry.safetensors`, or a run directory holding one, e.g. a `4dsg` run or an
    /// ablation's `geometry/`) written with the same scene and stage-1 settings; the result is
    /// that of an uninterrupted run.
    #[arg(long = "from-geometry", value_name = "RUN_DIR|FILE")]
    pub from_geometry: Option<PathBuf>,
    /// Gaussian methods and NAF: continue the run saved in the checkpoint (written when a run is
    /// interrupted with Ctrl-C / SIGTERM, diverges, or every `checkpoint_every` iterations);
    /// give the interrupted run's command and settings. The result is that of an uninterrupted
    /// run.
    #[arg(long)]
    pub resume: bool,
    /// Gaussian methods and NAF: the checkpoint file (default: `<out>.resume.safetensors` beside the
    /// output directory; removed when the run completes).
    #[arg(long = "checkpoint", value_name = "FILE")]
    pub checkpoint: Option<PathBuf>,
}

impl GaussianArgs {
    /// Run options for `config` (its device overridden by `--device`), reporting to `observer`
    /// and scoring under `evaluation`. A Gaussian or NAF run published to `out` is checkpointed (and
    /// stops cleanly on SIGINT / SIGTERM); without `out`, `--resume` and `--checkpoint` are
    /// refused.
    pub fn options<'a>(
        &'a self,
        config: &mut MethodConfig,
        observer: &'a Bars,
        evaluation: &'a Evaluation,
        out: Option<&Path>,
    ) -> anyhow::Result<RunOptions<'a>> {
        if let Some(d) = self.device {
            config.set_device(d.choice());
        }
        let checkpoint = match out {
            Some(out) if config.method().trains() => {
                let path = match &self.checkpoint {
                    Some(p) => p.clone(),
                    None => Checkpointing::default_path(out)?,
                };
                if !self.resume && path.is_file() {
                    eprintln!(
                        "warning: `{}` holds the state of an interrupted run; this run starts \
                         afresh (pass --resume to continue that one) and will replace it",
                        path.display()
                    );
                }
                Some(Checkpointing {
                    path,
                    resume: self.resume,
                    stop: Some(crate::interrupt::install()?),
                })
            }
            _ if self.resume || self.checkpoint.is_some() => bail!(
                "--resume and --checkpoint apply to a Gaussian method's or NAF's `prism recon` \
                 run (`{}` saves no training state)",
                config.method().name()
            ),
            _ => None,
        };
        let options = RunOptions {
            device: config.device().device()?,
            from_geometry: self.from_geometry.as_deref(),
            observer,
            evaluation,
            checkpoint,
        };
        options.check(config)?;
        Ok(options)
    }
}

/// Where a run is published.
#[derive(clap::Args)]
pub struct OutArgs {
    /// Output directory (a run: `<label>.npy` volumes, `config.resolved.yaml`, `metrics.json`,
    /// …), written beside it and published when the command succeeds.
    #[arg(short = 'o', long = "out")]
    pub out: PathBuf,
    /// Replace the run files of a directory that is not empty (files an earlier run did not
    /// write are kept).
    #[arg(long)]
    pub force: bool,
}

impl OutArgs {
    pub fn run_dir(&self) -> anyhow::Result<RunDir> {
        Ok(RunDir::create(&self.out, self.force)?)
    }
}

/// `--device` of the Gaussian methods.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum DeviceArg {
    Cpu,
    Wgpu,
}

impl DeviceArg {
    /// The argument's spelling on the command line.
    pub fn name(self) -> &'static str {
        match self {
            DeviceArg::Cpu => "cpu",
            DeviceArg::Wgpu => "wgpu",
        }
    }

    pub fn choice(self) -> DeviceChoice {
        match self {
            DeviceArg::Cpu => DeviceChoice::Cpu,
            DeviceArg::Wgpu => DeviceChoice::Wgpu,
        }
    }
}

/// `--dry-run` and `--allow-memory`: a command's peak-memory estimate, printed or checked.
#[derive(clap::Args)]
pub struct MemoryArgs {
    /// Print the estimated peak memory, item by item, and stop.
    #[arg(long)]
    pub dry_run: bool,
    /// Run even when the estimated peak memory exceeds the memory available.
    #[arg(long)]
    pub allow_memory: bool,
}

impl MemoryArgs {
    /// With `--dry-run`, print `estimate` under `config`'s name and return `false` (stop);
    /// otherwise refuse it above the memory available (unless `--allow-memory`, naming `what`)
    /// and return `true` (go on).
    pub fn proceed(
        &self,
        config: &std::path::Path,
        what: &str,
        estimate: &prism_domain::memory::Footprint,
    ) -> anyhow::Result<bool> {
        if self.dry_run {
            println!("{}: peak memory\n{}", config.display(), estimate.describe());
            return Ok(false);
        }
        estimate.check(what, self.allow_memory)?;
        Ok(true)
    }
}
