//! `prism import <import.yaml> -o <scene_dir>`: measured projections (counts with flat and dark
//! fields, or line integrals; `.npy`, TIFF, raw) of one or several acquisitions → a scene with
//! the selected training and test views and, by default, the full-view FDK of every channel as
//! its reference. See `docs/import.md` and `prism_recon::methods::classic::import`.

use crate::progress::Bars;
use anyhow::Context;
use prism_domain::import::{ImportConfig, footprint};
use prism_recon::methods::classic::import::{import_scene, reference_configs};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Import config (YAML); image paths are relative to it.
    config: PathBuf,
    /// Scene directory to write.
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    #[command(flatten)]
    memory: crate::args::MemoryArgs,
    #[command(flatten)]
    set: crate::args::SetArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(&args.config)
        .with_context(|| format!("reading {}", args.config.display()))?;
    let overrides = args.set.overrides()?;
    let config: ImportConfig = prism_domain::yaml::parse_with(&text, &args.config, &overrides)?;
    let base = args.config.parent().unwrap_or(std::path::Path::new("."));
    let footprint = footprint(&config, base).map_err(|e| e.in_file(&args.config))?;
    let what = format!("importing {}", args.config.display());
    if !args.memory.proceed(&args.config, &what, &footprint)? {
        return Ok(());
    }
    let bars = Bars::new();
    let references = reference_configs(&config, base)?;
    let mut scene = import_scene(&config, base, &text, references.as_deref(), &bars)
        .map_err(|e| e.in_file(&args.config))?;
    scene.provenance.overrides = overrides.texts();
    scene.save(&args.out)?;
    bars.finish();
    let references = match references {
        Some(r) => {
            let mut from: Vec<&str> = r.iter().map(|(_, f)| f.as_str()).collect();
            from.dedup();
            format!("references: full-view {}", from.join(", "))
        }
        None => "no references".into(),
    };
    let scan = config.angles_rad(base)?.len();
    eprintln!(
        "{}: {} channels, {} training + {} test views of {scan} ({references}) → {}",
        scene.name,
        scene.n_channels(),
        scene.split.train.len(),
        scene.split.test.len(),
        args.out.display()
    );
    Ok(())
}
