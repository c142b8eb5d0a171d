//! `prism import <import.yaml> -o <scene_dir>`: measured projections (counts with flat and dark
//! fields, or line integrals; `.npy`, TIFF, raw) of one or several acquisitions → a scene with
//! the selected training and test views and, by default, the full-view FDK of every channel as
//! its reference. See `docs/import.md` and `prism_domain::import`.

use crate::progress::Bars;
use anyhow::Context;
use prism_domain::import::{ImportConfig, ReferenceKind, assemble, footprint};
use prism_domain::observe::{Level, Observer};
use prism_recon::methods::classic::{ClassicConfig, ClassicMethod, reconstruct_channel};
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
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(&args.config)
        .with_context(|| format!("reading {}", args.config.display()))?;
    let config: ImportConfig =
        prism_domain::yaml::parse_with(&text, &args.config, &Default::default())?;
    let base = args.config.parent().unwrap_or(std::path::Path::new("."));
    let footprint = footprint(&config, base).map_err(|e| e.in_file(&args.config))?;
    let what = format!("importing {}", args.config.display());
    if !args.memory.proceed(&args.config, &what, &footprint)? {
        return Ok(());
    }
    let bars = Bars::new();
    bars.phase("reading and converting the images", 0);
    let full = assemble(&config, base, &text).map_err(|e| e.in_file(&args.config))?;
    for (ch, n) in full.scene.channels.iter().zip(&full.raised) {
        if *n > 0 {
            bars.note(
                Level::Warning,
                &format!(
                    "channel `{}`: {n} pixels had dark-corrected counts below min_counts = {} and were raised to it",
                    ch.label, config.min_counts
                ),
            );
        }
    }
    let mut scene = full.scene;
    let n = scene.n_views();
    if config.select.reference == ReferenceKind::Fdk {
        let fdk = ClassicConfig {
            method: ClassicMethod::Fdk,
            ..ClassicConfig::default()
        };
        bars.phase("full-view FDK references", scene.n_channels() as u64);
        let volumes = (0..scene.n_channels())
            .map(|c| {
                let views: Vec<usize> = (0..n).filter(|&v| scene.availability[[v, c]]).collect();
                let v = reconstruct_channel(
                    &fdk,
                    &scene.geometry,
                    scene.channel_projections(c),
                    &views,
                    &mut |_| {},
                );
                bars.progress(c as u64 + 1, &scene.channels[c].label);
                v
            })
            .collect::<Result<Vec<_>, _>>()?;
        scene = scene.with_references(volumes)?;
    }
    let (train, test) = config.pick_views(n).map_err(|e| e.in_file(&args.config))?;
    let scene = scene.with_views(&train, &test)?;
    scene.save(&args.out)?;
    bars.finish();
    eprintln!(
        "{}: {} channels, {} training + {} test views of {n} ({}), → {}",
        scene.name,
        scene.n_channels(),
        train.len(),
        test.len(),
        match config.select.reference {
            ReferenceKind::Fdk => "references: full-view FDK",
            ReferenceKind::None => "no references",
        },
        args.out.display()
    );
    Ok(())
}
