//! `prism recon <config.yaml> -s <scene_dir> -o <run_dir>`: reconstruct every channel of a scene
//! with a classic method (`fdk | sart | cgls`, see `prism_core::classic::recon`) or a Gaussian
//! one (`r2gs | 4dsg-stage1 | 4dsg`, see `prism_core::gaussian::run`; `--from-geometry`
//! continues a 4D-SG run from its stage-1 checkpoint).

use prism_core::classic::recon::METRICS_FILE;
use prism_core::gaussian::DeviceChoice;
use prism_core::method::MethodConfig;
use prism_core::scene::Scene;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ReconArgs {
    /// Reconstruction config (YAML) with `method: fdk | sart | cgls | r2gs | 4dsg-stage1` and that
    /// method's settings (see configs/recon/).
    config: PathBuf,
    /// Scene directory (scene.yaml + .npy arrays).
    #[arg(short = 's', long = "scene")]
    scene: PathBuf,
    /// Run directory for `<label>.npy` volumes, `config.resolved.yaml` and `metrics.json`
    /// (Gaussian methods add `log.jsonl`, `train.json` and the trained Gaussians).
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// Compute device of a Gaussian method (overrides the config's `device`): `cpu`, or `wgpu`
    /// in a prism built with `--features wgpu` (a GPU, or Mesa's lavapipe without one).
    #[arg(long = "device")]
    device: Option<DeviceArg>,
    /// `4dsg` / `4dsg-stage1` only: skip stage 1 and continue from its checkpoint
    /// (`geometry.safetensors`, or a run directory holding one) written by an earlier run with the
    /// same scene and stage-1 settings; the result is that of an uninterrupted run.
    #[arg(long = "from-geometry", value_name = "RUN_DIR|FILE")]
    from_geometry: Option<PathBuf>,
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

pub fn run(args: ReconArgs) -> anyhow::Result<()> {
    let mut config = MethodConfig::load(&args.config)?;
    if let (MethodConfig::Gaussian(c), Some(d)) = (&mut config, args.device) {
        c.device = d.choice();
    }
    let device = match &config {
        MethodConfig::Gaussian(c) => c.device.device()?,
        MethodConfig::Classic(_) => DeviceChoice::Cpu.device()?,
    };
    let scene = Scene::load(&args.scene)?;
    let report = match (&config, &args.from_geometry) {
        (MethodConfig::Gaussian(c), Some(from)) => {
            prism_core::gaussian::run::run_from(c, &scene, &args.out, &device, Some(from))?
        }
        (MethodConfig::Classic(_), Some(_)) => {
            anyhow::bail!(
                "--from-geometry applies to the Gaussian methods `4dsg` and `4dsg-stage1`"
            )
        }
        _ => config.run(&scene, &args.out, &device)?,
    };
    match report {
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
                args.out.join(METRICS_FILE).display()
            );
        }
        None => eprintln!(
            "the scene has no reference volumes; volumes written to {}",
            args.out.display()
        ),
    }
    Ok(())
}
