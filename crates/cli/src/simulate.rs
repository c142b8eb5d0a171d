//! `prism simulate <config.yaml> -o <scene_dir> [--set key=value …]`.

use crate::args::{MemoryArgs, SetArgs};
use crate::progress::Bars;
use anyhow::Context;
use prism_domain::observe::Observer;
use prism_domain::simulate::{SimulateConfig, simulate};
use prism_domain::yaml::Overrides;
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
    /// Use the paper's resolution (256³ volume, 512² detector), keeping every physical size
    /// (the same as three `--set` overrides of `geometry.volume.n` and `geometry.detector`).
    #[arg(long)]
    paper_scale: bool,
    #[command(flatten)]
    memory: MemoryArgs,
    #[command(flatten)]
    set: SetArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut overrides = Overrides::default();
    if args.paper_scale {
        overrides = SimulateConfig::paper_scale();
    }
    let overrides = overrides.then(&args.set.overrides()?);
    let start = Instant::now();
    let bars = Bars::new();
    let cfg = SimulateConfig::load_with(&args.config, &overrides)?;
    let footprint = cfg.footprint().map_err(|e| e.in_file(&args.config))?;
    let what = format!("simulating {}", args.config.display());
    if !args.memory.proceed(&args.config, &what, &footprint)? {
        return Ok(());
    }
    let mut scene = simulate(&cfg, Some(&args.config), &bars)?;
    scene.provenance.overrides = overrides.texts();
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
