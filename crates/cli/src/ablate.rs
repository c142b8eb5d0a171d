//! `prism ablate <freeze|curve-model> <config.yaml> -s <scene_dir> -o <out_dir>`: 4D-SG stage-2
//! ablations from one shared stage 1 (see `prism_recon::pipeline::ablation`).

use crate::progress::Bars;
use crate::recon::{DeviceArg, OutArgs};
use anyhow::bail;
use prism_domain::scene::Scene;
use prism_recon::MethodConfig;
use prism_recon::gaussian::GaussianMethod;
use prism_recon::pipeline::RunOptions;
use prism_recon::pipeline::ablation::{Study, ablate, markdown};
use std::path::PathBuf;

#[derive(Clone, Copy, clap::ValueEnum)]
enum StudyArg {
    /// The paper's freezing strategies: P/R/S/D learnable or frozen in stage 2.
    Freeze,
    /// GSC-Net against the direct MLP.
    CurveModel,
}

#[derive(clap::Args)]
pub struct Args {
    /// What to vary.
    #[arg(value_enum)]
    study: StudyArg,
    /// A `method: 4dsg` config (e.g. configs/recon/4dsg.yaml); its `stage2` is the base.
    config: PathBuf,
    /// Scene directory (scene.yaml + .npy arrays).
    #[arg(short = 's', long = "scene")]
    scene: PathBuf,
    // Output (`-o`): `geometry/` (the shared stage 1 and its checkpoint), one run directory per
    // variant, `ablation.json` and `ablation.md`.
    #[command(flatten)]
    out: OutArgs,
    /// Compute device (overrides the config's `device`): `cpu`, or `wgpu` in a prism built with
    /// `--features wgpu`.
    #[arg(long = "device")]
    device: Option<DeviceArg>,
    /// Skip stage 1 and start every variant from this stage-1 checkpoint
    /// (`geometry.safetensors`, or a run directory holding one, e.g. a `4dsg` recon run or an
    /// earlier ablation's `geometry/`) of the same scene and stage-1 settings.
    #[arg(long = "from-geometry", value_name = "RUN_DIR|FILE")]
    from_geometry: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut config = match MethodConfig::load(&args.config)? {
        MethodConfig::Gaussian(c) if c.method == GaussianMethod::FourDsg => c,
        _ => bail!(
            "{}: field `method`: ablations vary stage 2 and need `method: 4dsg`",
            args.config.display()
        ),
    };
    let scene = Scene::load(&args.scene)?;
    let study = match args.study {
        StudyArg::Freeze => Study::Freeze,
        StudyArg::CurveModel => Study::CurveModel,
    };
    if let Some(d) = args.device {
        config.device = d.choice();
    }
    let bars = Bars::new();
    let options = RunOptions {
        device: config.device.device()?,
        from_geometry: args.from_geometry.as_deref(),
        observer: &bars,
    };
    let (dir, report) = ablate(&config, study, &scene, args.out.run_dir()?, &options)?;
    bars.finish();
    print!("{}", markdown(&report));
    eprintln!("→ {}", dir.join("ablation.json").display());
    Ok(())
}
