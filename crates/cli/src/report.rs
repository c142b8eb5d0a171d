//! `prism report <run_dir>...`: one per-channel PSNR/SSIM table over finished runs (see
//! `prism_recon::report`), with the paths of the written volumes; with `--html`, the same as a
//! page to browse, with PSNR against time and a slice viewer (`prism_experiment::html`).

use crate::progress::Bars;
use prism_experiment::html::write_runs_page;
use prism_recon::report::{RunScores, column_names, table};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Run directories written by `prism recon` (each with `metrics.json`).
    #[arg(required = true)]
    runs: Vec<PathBuf>,
    /// Also write this HTML page (its viewer's volumes in `<page stem>-data/` beside it).
    #[arg(long, value_name = "FILE")]
    html: Option<PathBuf>,
    /// The scene directory the runs reconstructed: the page's viewer shows its reference volumes
    /// and each run's residual against them.
    #[arg(long, value_name = "DIR", requires = "html")]
    scene: Option<PathBuf>,
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
    if let Some(page) = &args.html {
        let bars = Bars::new();
        let p = write_runs_page(&runs, args.scene.as_deref(), page, &bars)?;
        bars.finish();
        eprintln!(
            "{} ({:.1} MB with {})",
            p.html.display(),
            p.bytes as f64 / 1e6,
            p.data.display()
        );
    }
    Ok(())
}
