//! `prism simulate <config.yaml> -o <scene_dir>`.

use crate::progress::Bars;
use anyhow::Context;
use prism_domain::observe::Observer;
use prism_domain::simulate::{SimulateConfig, simulate};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args)]
pub struct Args {
    /// Scene config (YAML), e.g. configs/phantom-3mono.yaml.
    config: PathBuf,
    /// Output scene directory (written beside it and published when done; an existing scene's
    /// files are replaced, other files in the directory are kept).
    #[arg(short, long)]
    output: PathBuf,
    /// Use the paper's resolution (256³ volume, 512² detector), keeping every physical size.
    #[arg(long)]
    paper_scale: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut config = SimulateConfig::load(&args.config)?;
    if args.paper_scale {
        config = config.at_paper_scale();
    }
    let start = Instant::now();
    let bars = Bars::new();
    let scene = simulate(&config, Some(&args.config), &bars)?;
    bars.phase(&format!("writing {}", args.output.display()), 0);
    scene
        .save(&args.output)
        .with_context(|| format!("writing scene {}", args.output.display()))?;
    bars.finish();
    println!(
        "wrote {} ({} channels, {} views, {:.1} s)",
        args.output.display(),
        scene.channels.len(),
        scene.geometry.views(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
