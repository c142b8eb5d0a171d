//! `prism ablate <freeze|curve-model> <config.yaml> -s <scene_dir> -o <out_dir>`: 4D-SG stage-2
//! ablations from one shared stage 1 (see `prism_core::gaussian::ablation`).

use anyhow::bail;
use prism_core::gaussian::ablation::{Study, ablate, markdown};
use prism_core::gaussian::{GaussianMethod, cpu_device};
use prism_core::method::MethodConfig;
use prism_core::scene::Scene;
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
    /// Output directory: `geometry/` (the shared stage 1), one run directory per variant,
    /// `ablation.json` and `ablation.md`.
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match MethodConfig::load(&args.config)? {
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
    let report = ablate(&config, study, &scene, &args.out, &cpu_device())?;
    print!("{}", markdown(&report));
    eprintln!("→ {}", args.out.join("ablation.json").display());
    Ok(())
}
