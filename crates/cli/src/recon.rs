//! `prism recon <config.yaml> -s <scene_dir> -o <run_dir>`: classic reconstruction (FDK, the SART
//! family, CGLS) of every channel of a scene; see `prism_core::classic::recon`.

use prism_core::classic::recon::{self, METRICS_FILE, ReconConfig};
use prism_core::scene::Scene;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ReconArgs {
    /// Reconstruction config (YAML): `method: fdk | sart | cgls` plus optional `filter`,
    /// `iterations`, `block_size`, `lambda`, `lambda_decay`, `order`, `nonneg`, `seed`.
    config: PathBuf,
    /// Scene directory (scene.yaml + .npy arrays).
    #[arg(short = 's', long = "scene")]
    scene: PathBuf,
    /// Run directory for `<label>.npy` volumes, `config.resolved.yaml` and `metrics.json`.
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
}

pub fn run(args: ReconArgs) -> anyhow::Result<()> {
    let config = ReconConfig::load(&args.config)?;
    let scene = Scene::load(&args.scene)?;
    match recon::run(&config, &scene, &args.out)? {
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
