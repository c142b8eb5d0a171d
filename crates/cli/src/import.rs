//! `prism import <import.yaml> -o <scene_dir>`: measured projections (counts with flat and dark
//! fields, or line integrals; `.npy`, TIFF, raw) of one or several acquisitions → a scene with
//! the selected training and test views and, by default, the full-view FDK of every channel as
//! its reference. See `docs/import.md` and `prism_recon::methods::classic::import`.

use crate::progress::Bars;
use anyhow::Context;
use prism_domain::import::{ImportConfig, footprint};
use prism_domain::yaml::Overrides;
use prism_recon::methods::classic::import::{Reference, import_scene, reference_configs};
use std::path::{Path, PathBuf};

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

/// An import config read with its overrides: the config, its text and the overrides.
pub struct Read {
    pub config: ImportConfig,
    pub text: String,
    pub overrides: Overrides,
}

/// Read and check `path` with `set`'s overrides, and its memory estimate against `memory`
/// (`doing` names the work in the refusal); `None` after a dry run.
pub fn read_config(
    path: &Path,
    set: &crate::args::SetArgs,
    memory: &crate::args::MemoryArgs,
    doing: &str,
) -> anyhow::Result<Option<Read>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let overrides = set.overrides()?;
    let config: ImportConfig = prism_domain::yaml::parse_with(&text, path, &overrides)?;
    let base = path.parent().unwrap_or(Path::new("."));
    let footprint = footprint(&config, base).map_err(|e| e.in_file(path))?;
    let what = format!("{doing} {}", path.display());
    if !memory.proceed(path, &what, &footprint)? {
        return Ok(None);
    }
    Ok(Some(Read {
        config,
        text,
        overrides,
    }))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Some(Read {
        config,
        text,
        overrides,
    }) = read_config(&args.config, &args.set, &args.memory, "importing")?
    else {
        return Ok(());
    };
    let base = args.config.parent().unwrap_or(Path::new("."));
    let bars = Bars::new();
    let references = reference_configs(&config, base)?;
    let mut scene = import_scene(&config, base, &text, references.as_deref(), &bars)
        .map_err(|e| e.in_file(&args.config))?;
    scene.provenance.overrides = overrides.texts();
    scene.save(&args.out)?;
    bars.finish();
    let references = match references {
        Some(r) => {
            let (mut recon, mut files) = (Vec::new(), Vec::new());
            for r in &r {
                match r {
                    Reference::Recon(..) => recon.push(r.describe()),
                    Reference::Volume(_) => files.push(r.describe()),
                }
            }
            recon.dedup();
            let mut parts = Vec::new();
            if !recon.is_empty() {
                parts.push(format!("full-view {}", recon.join(", ")));
            }
            if !files.is_empty() {
                parts.push(format!("read from {}", files.join(", ")));
            }
            format!("references: {}", parts.join("; "))
        }
        None => "no references".into(),
    };
    let scan = config.scan_geometry(base)?.0.views();
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
