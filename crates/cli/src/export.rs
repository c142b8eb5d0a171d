//! `prism export <scene> [VOLUMES...] -o <dir> --format nii.gz --format mha`: volumes as NIfTI-1
//! or MetaImage files with the voxel spacing and grid position of the scene's geometry, for a
//! viewer (3D Slicer, ITK-SNAP, napari) or another tool. See `prism_domain::export` for the
//! conventions.

use anyhow::{Context, bail};
use prism_domain::export::{VolumeFormat, read_volume_npy, write_volume};
use prism_domain::scene::Scene;
use prism_recon::record::RunDir;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// Scene directory: its geometry places the volumes; without VOLUMES its reference volumes
    /// are exported (`reference-<channel>`).
    scene: PathBuf,
    /// Volumes on the scene's grid: `.npy` files (`prism query -o`) or run directories (every
    /// volume a run wrote, `prism recon -o`). Each is written as `<file stem>.<format>`.
    volumes: Vec<PathBuf>,
    /// Output directory (created if missing).
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// nii, nii.gz, mha, tif, or png (a preview of the central slices); repeatable.
    #[arg(long = "format", required = true, value_parser = parse_format)]
    formats: Vec<VolumeFormat>,
    /// Replace output files that exist (without it, an existing file stops the export before
    /// anything is written).
    #[arg(long)]
    force: bool,
}

fn parse_format(s: &str) -> Result<VolumeFormat, String> {
    VolumeFormat::parse(s).map_err(|e| e.to_string())
}

/// What to write: output stem → the volume's source.
enum Source {
    Reference(usize),
    File(PathBuf),
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let scene = Scene::open(&args.scene)?;
    let mut sources: BTreeMap<String, Source> = BTreeMap::new();
    let mut add = |stem: String, source: Source, from: &Path| -> anyhow::Result<()> {
        if sources.insert(stem.clone(), source).is_some() {
            bail!(
                "{}: a second volume named `{stem}` (export volumes with the same name into different directories)",
                from.display()
            );
        }
        Ok(())
    };
    if args.volumes.is_empty() {
        if scene.references.is_none() {
            bail!(
                "{}: the scene has no reference volumes; name the volumes to export",
                args.scene.display()
            );
        }
        for (c, ch) in scene.channels.iter().enumerate() {
            let stem = format!("reference-{}", RunDir::stem(&ch.label));
            add(stem, Source::Reference(c), &args.scene)?;
        }
    }
    for v in &args.volumes {
        for file in volume_files(v)? {
            let stem = file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            add(stem, Source::File(file), v)?;
        }
    }
    // Every target is checked before anything is written.
    if !args.force {
        for stem in sources.keys() {
            for format in &args.formats {
                prism_domain::staged::refuse_existing(&format.path(&args.out, stem))?;
            }
        }
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let grid = &scene.geometry.volume;
    for (stem, source) in &sources {
        let (volume, what) = match source {
            Source::Reference(c) => {
                let r = scene.reference(*c).context("no reference volumes")?;
                (
                    r.to_owned(),
                    format!("{} reference {}", scene.name, scene.channels[*c].label),
                )
            }
            Source::File(f) => (read_volume_npy(f)?, f.display().to_string()),
        };
        for &format in &args.formats {
            let path = format.path(&args.out, stem);
            write_volume(
                &path,
                volume.view(),
                grid,
                format,
                &format!("prism: {what}"),
            )
            .with_context(|| format!("{what} on the grid of {}", args.scene.display()))?;
            eprintln!("wrote {}", path.display());
        }
    }
    Ok(())
}

/// The `.npy` volumes a path names: the file itself, or the volumes a run directory wrote.
fn volume_files(path: &Path) -> anyhow::Result<Vec<PathBuf>> {
    if path.is_dir() {
        let manifest = RunDir::manifest(path)?;
        if manifest.files.is_empty() {
            bail!(
                "{}: not a run directory (no {}); name its .npy volumes instead",
                path.display(),
                RunDir::MANIFEST
            );
        }
        let files: Vec<PathBuf> = manifest
            .files
            .iter()
            .filter(|f| f.ends_with(".npy"))
            .map(|f| path.join(f))
            .collect();
        if files.is_empty() {
            bail!("{}: the run wrote no volumes", path.display());
        }
        Ok(files)
    } else if path.extension().is_some_and(|e| e == "npy") {
        Ok(vec![path.to_path_buf()])
    } else {
        bail!(
            "{}: expected a .npy volume or a run directory",
            path.display()
        )
    }
}
