//! `prism recon <config.yaml> -s <scene_dir> -o <run_dir>`: reconstruct every channel of a scene
//! with any method (`configs/recon/`), through `prism_recon::pipeline::run`.

use crate::args::{EvalArgs, GaussianArgs, MemoryArgs, OutArgs, SetArgs};
use crate::progress::Bars;
use prism_domain::scene::Scene;
use prism_recon::MethodConfig;
use prism_recon::pipeline::{run, run_footprint};
use prism_recon::record::RunDir;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ReconArgs {
    /// Reconstruction config (YAML) with `method: fdk | sart | cgls | tv | naf | r2gs | 4dsg-stage1 | 4dsg`
    /// and that method's settings (see configs/recon/).
    config: PathBuf,
    /// Scene directory (scene.yaml + .npy arrays), or an R²-Gaussian case folder
    /// (meta_data.json; one channel).
    #[arg(short = 's', long = "scene")]
    scene: PathBuf,
    #[command(flatten)]
    out: OutArgs,
    #[command(flatten)]
    gaussian: GaussianArgs,
    #[command(flatten)]
    eval: EvalArgs,
    #[command(flatten)]
    memory: MemoryArgs,
    #[command(flatten)]
    set: SetArgs,
}

pub fn run_cmd(args: ReconArgs) -> anyhow::Result<()> {
    let mut config = MethodConfig::load_with(&args.config, &args.set.overrides()?)?;
    let scene = Scene::open(&args.scene)?;
    let what = format!("{} on {}", config.method().name(), args.scene.display());
    let evaluation = args.eval.evaluation()?;
    let peak = run_footprint(&config, &scene, &evaluation);
    if !args.memory.proceed(&args.config, &what, &peak)? {
        return Ok(());
    }
    let bars = Bars::new();
    let options = args
        .gaussian
        .options(&mut config, &bars, &evaluation, Some(&args.out.out))?;
    let outcome = run(&config, &scene, args.out.run_dir()?, &options)?;
    bars.finish();
    match outcome.metrics {
        Some(report) => {
            let lpips = |v: Option<f64>| v.map_or(String::new(), |v| format!("  LPIPS {v:.4}"));
            eprintln!("{:>12}  PSNR (volume / slices)  SSIM (volume / slices)", "");
            for c in &report.channels {
                let s = &c.scores;
                eprintln!(
                    "{:>12}  {:6.2} / {:6.2} dB     {:.4} / {:.4}{}",
                    c.label,
                    s.psnr,
                    s.psnr_slices,
                    s.ssim,
                    s.ssim_slices,
                    lpips(s.lpips)
                );
            }
            let m = &report.mean;
            eprintln!(
                "{:>12}  {:6.2} / {:6.2} dB     {:.4} / {:.4}{}  ({:.2} s) → {}",
                "mean",
                m.psnr,
                m.psnr_slices,
                m.ssim,
                m.ssim_slices,
                lpips(m.lpips),
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
