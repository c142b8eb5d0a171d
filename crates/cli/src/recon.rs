//! `prism recon <config.yaml> -s <scene_dir> -o <run_dir>`: reconstruct every channel of a scene
//! with any method (`configs/recon/`), through `prism_recon::pipeline::run`.

use crate::progress::Bars;
use prism_domain::scene::Scene;
use prism_recon::MethodConfig;
use prism_recon::gaussian::DeviceChoice;
use prism_recon::pipeline::{RunDir, RunOptions, run};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ReconArgs {
    /// Reconstruction config (YAML) with `method: fdk | sart | cgls | r2gs | 4dsg-stage1 | 4dsg`
    /// and that method's settings (see configs/recon/).
    config: PathBuf,
    /// Scene directory (scene.yaml + .npy arrays).
    #[arg(short = 's', long = "scene")]
    scene: PathBuf,
    #[command(flatten)]
    out: OutArgs,
    #[command(flatten)]
    gaussian: GaussianArgs,
}

/// Where a Gaussian method runs and what it starts from.
#[derive(clap::Args)]
pub struct GaussianArgs {
    /// Compute device of a Gaussian method (overrides the config's `device`): `cpu`, or `wgpu`
    /// in a prism built with `--features wgpu` (a GPU, or Mesa's lavapipe without one).
    #[arg(long = "device")]
    pub device: Option<DeviceArg>,
    /// `4dsg` / `4dsg-stage1` only: skip stage 1 and continue from its checkpoint
    /// (`geometry.safetensors`, or a run directory holding one, e.g. a `4dsg` run or an
    /// ablation's `geometry/`) written with the same scene and stage-1 settings; the result is
    /// that of an uninterrupted run.
    #[arg(long = "from-geometry", value_name = "RUN_DIR|FILE")]
    pub from_geometry: Option<PathBuf>,
}

impl GaussianArgs {
    /// Run options for `config` (its device overridden by `--device`), reporting to `observer`.
    pub fn options<'a>(
        &'a self,
        config: &mut MethodConfig,
        observer: &'a Bars,
    ) -> anyhow::Result<RunOptions<'a>> {
        if let Some(d) = self.device {
            config.set_device(d.choice());
        }
        let options = RunOptions {
            device: config.device().device()?,
            from_geometry: self.from_geometry.as_deref(),
            observer,
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
    pub fn choice(self) -> DeviceChoice {
        match self {
            DeviceArg::Cpu => DeviceChoice::Cpu,
            DeviceArg::Wgpu => DeviceChoice::Wgpu,
        }
    }
}

pub fn run_cmd(args: ReconArgs) -> anyhow::Result<()> {
    let mut config = MethodConfig::load(&args.config)?;
    let scene = Scene::load(&args.scene)?;
    let bars = Bars::new();
    let options = args.gaussian.options(&mut config, &bars)?;
    let outcome = run(&config, &scene, args.out.run_dir()?, &options)?;
    bars.finish();
    match outcome.metrics {
        Some(report) => {
            for c in &report.channels {
                eprintln!(
                    "{:>12}  PSNR {:6.2} dB  SSIM {:.4}",
                    c.label, c.psnr, c.ssim
                );
            }
            eprintln!(
                "{:>12}  PSNR {:6.2} dB  SSIM {:.4}  ({:.2} s) → {}",
                "mean",
                report.mean.psnr,
                report.mean.ssim,
                report.wall_s,
                outcome.dir.join(RunDir::METRICS).display()
            );
        }
        None => eprintln!(
            "the scene has no reference volumes; volumes written to {}",
            outcome.dir.display()
        ),
    }
    Ok(())
}
