//! `prism simulate <config.yaml> -o <scene_dir>`.

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use prism_core::simulate::{SimulateConfig, simulate};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args)]
pub struct Args {
    /// Scene config (YAML), e.g. configs/phantom-3mono.yaml.
    config: PathBuf,
    /// Output scene directory (replaced atomically if it exists).
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
    let bar = ProgressBar::with_draw_target(None, prism_core::progress::target()).with_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
            .expect("static template"),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let scene = simulate(&config, Some(&args.config), &bar)?;
    bar.set_message(format!("writing {}", args.output.display()));
    scene
        .save(&args.output)
        .with_context(|| format!("writing scene {}", args.output.display()))?;
    bar.finish_and_clear();
    println!(
        "wrote {} ({} channels, {} views, {:.1} s)",
        args.output.display(),
        scene.channels.len(),
        scene.geometry.views(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
