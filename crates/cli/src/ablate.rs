//! `prism ablate <freeze|curve-model> <config.yaml> -s <scene_dir> -o <out_dir>`: 4D-SG stage-2
//! ablations from one shared stage 1 (see `prism_recon::methods::fourdsg::ablation`).

use crate::args::{EvalArgs, GaussianArgs, OutArgs, SetArgs};
use crate::progress::Bars;
use anyhow::bail;
use prism_domain::scene::Scene;
use prism_recon::MethodConfig;
use prism_recon::methods::fourdsg::FourDsgMethod;
use prism_recon::methods::fourdsg::ablation::{Study, ablate, markdown};
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
    #[command(flatten)]
    gaussian: GaussianArgs,
    #[command(flatten)]
    eval: EvalArgs,
    #[command(flatten)]
    set: SetArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut config = MethodConfig::load_with(&args.config, &args.set.overrides()?)?;
    let evaluation = args.eval.evaluation()?;
    let bars = Bars::new();
    let options = args
        .gaussian
        .options(&mut config, &bars, &evaluation, None)?;
    let base = match &config {
        MethodConfig::FourDsg(c) if c.method == FourDsgMethod::Full => c,
        _ => bail!(
            "{}: field `method`: ablations vary stage 2 and need `method: 4dsg`",
            args.config.display()
        ),
    };
    let scene = Scene::open(&args.scene)?;
    let study = match args.study {
        StudyArg::Freeze => Study::Freeze,
        StudyArg::CurveModel => Study::CurveModel,
    };
    let (dir, report) = ablate(base, study, &scene, args.out.run_dir()?, &options)?;
    bars.finish();
    print!("{}", markdown(&report));
    eprintln!(
        "→ {}",
        dir.join(prism_recon::record::RunDir::ABLATION).display()
    );
    Ok(())
}
