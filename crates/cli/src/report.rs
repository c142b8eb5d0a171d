//! `prism report <run_dir>...`: one per-channel PSNR/SSIM table over finished runs (see
//! `prism_recon::report`), with the paths of the written volumes.

use prism_recon::report::{RunScores, column_names, table};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Run directories written by `prism recon` (each with `metrics.json`).
    #[arg(required = true)]
    runs: Vec<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let runs = args
        .runs
        .iter()
        .map(|d| RunScores::load(d))
        .collect::<Result<Vec<_>, _>>()?;
    print!("{}", table(&runs));
    println!();
    for (r, name) in runs.iter().zip(column_names(&runs)) {
        println!("{name} volumes (mm⁻¹, [z][y][x]):");
        for c in &r.channels {
            println!("  {}", c.volume.display());
        }
    }
    Ok(())
}
