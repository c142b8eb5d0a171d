//! `prism decompose <run_dir> -s <scene_dir> -o <out_dir> [--basis …] [--kev …]`: basis-material
//! fractions and virtual monoenergetic images from a run's channel volumes (the image-domain
//! step of a two-step decomposition; see `prism_domain::decompose`).

use anyhow::{Context, bail};
use ndarray::Array3;
use prism_domain::decompose::{Basis, Decomposition, channel_specs, vmi};
use prism_domain::metrics::psnr::psnr;
use prism_domain::physics::{ChannelSpec, Material};
use prism_domain::scene::Scene;
use prism_recon::pipeline::RunDir;
use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// Run directory holding one `<label>.npy` volume (mm⁻¹) per channel of the scene.
    run_dir: PathBuf,
    /// The scene the run reconstructed (its channels' spectra; its references, if any, are
    /// decomposed too and the run is scored against them).
    #[arg(short = 's', long = "scene")]
    scene: PathBuf,
    /// Output directory (created; must not exist or be empty).
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// Basis materials, comma-separated (1 to 4 of the attenuation table's).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "water,cortical_bone,iodine"
    )]
    basis: Vec<String>,
    /// Energies (keV, 10–150) of virtual monoenergetic images to write, comma-separated.
    #[arg(long, value_delimiter = ',')]
    kev: Vec<f64>,
}

/// `decomposition.json`.
#[derive(Serialize)]
struct Report {
    run_dir: String,
    basis: Vec<&'static str>,
    /// The fraction files: volume fraction of each basis material at its nominal density.
    fractions: Vec<String>,
    /// How each channel's basis attenuation was computed, and whether it is the scene's own.
    channels: Vec<(String, ChannelSpec)>,
    spectra_exact: bool,
    /// `[channel][basis]`, mm⁻¹.
    matrix: Vec<Vec<f64>>,
    condition: f64,
    /// Standard deviation of each fraction per mm⁻¹ of channel-volume noise.
    noise_gain: Vec<f64>,
    vmi: Vec<Vmi>,
    /// Against the decomposition of the scene's reference volumes, inside the body (voxels
    /// where any reference exceeds 1 % of its maximum).
    against_references: Option<Scores>,
}

#[derive(Serialize)]
struct Vmi {
    kev: f64,
    file: String,
    /// Outside the channels' energies: an extrapolation of the basis model.
    extrapolated: bool,
}

#[derive(Serialize)]
struct Scores {
    voxels: usize,
    /// Per basis material: RMSE of the fraction.
    fraction_rmse: Vec<f64>,
    /// Per VMI energy: PSNR (dB, peak = the reference VMI's maximum) over the whole volume.
    vmi_psnr: Vec<f64>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let materials = args
        .basis
        .iter()
        .map(|n| Material::from_name(n.trim()))
        .collect::<Result<Vec<_>, _>>()?;
    let basis = Basis::new(&materials)?;
    let scene = Scene::load(&args.scene)?;
    let (specs, exact) = channel_specs(&scene)?;
    if !exact {
        eprintln!(
            "warning: {} records no channel spectra; tube voltages are taken with the default \
             filtration",
            args.scene.display()
        );
    }
    let d = Decomposition::new(basis.clone(), &specs)
        .map_err(|e| e.in_file(args.scene.join("scene.yaml")))?;
    let volumes = scene
        .channels
        .iter()
        .map(|ch| read_volume(&args.run_dir.join(RunDir::volume_file(&ch.label))))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let views: Vec<_> = volumes.iter().map(|v| v.view()).collect();
    let fractions = d.volumes(&views)?;
    let (lo, hi) = mono_range(&specs);
    for &e in &args.kev {
        prism_domain::physics::attenuation::check_energy(e, "--kev")?;
        if lo.is_none_or(|lo| e < lo) || hi.is_none_or(|hi| e > hi) {
            eprintln!(
                "warning: {e} keV lies outside the channels' energies: its VMI extrapolates the \
                 basis model"
            );
        }
    }
    let vmis = args
        .kev
        .iter()
        .map(|&e| vmi(&basis, &fractions, e))
        .collect::<Result<Vec<_>, _>>()?;
    let against_references = match &scene.references {
        Some(r) => {
            let refs: Vec<_> = r.outer_iter().collect();
            let truth = d.volumes(&refs)?;
            let truth_vmis = args
                .kev
                .iter()
                .map(|&e| vmi(&basis, &truth, e))
                .collect::<Result<Vec<_>, _>>()?;
            // The body: voxels where any reference exceeds 1 % of the largest value.
            let peak = r.iter().fold(0.0f32, |a, &v| a.max(v));
            let mut body = Array3::from_elem(truth[0].dim(), false);
            for v in &refs {
                ndarray::Zip::from(&mut body)
                    .and(v)
                    .for_each(|b, &x| *b |= x > 0.01 * peak);
            }
            let voxels = body.iter().filter(|&&b| b).count().max(1);
            let fraction_rmse = fractions
                .iter()
                .zip(&truth)
                .map(|(f, t)| {
                    let se: f64 =
                        ndarray::Zip::from(f)
                            .and(t)
                            .and(&body)
                            .fold(0.0, |a, &f, &t, &b| {
                                a + if b {
                                    (f as f64 - t as f64).powi(2)
                                } else {
                                    0.0
                                }
                            });
                    (se / voxels as f64).sqrt()
                })
                .collect();
            let vmi_psnr = vmis
                .iter()
                .zip(&truth_vmis)
                .map(|(v, t)| {
                    let peak = t.iter().fold(0.0f32, |a, &x| a.max(x)) as f64;
                    psnr(v.view(), t.view(), peak)
                })
                .collect::<Result<Vec<_>, _>>()?;
            Some(Scores {
                voxels,
                fraction_rmse,
                vmi_psnr,
            })
        }
        None => None,
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    if std::fs::read_dir(&args.out)?.next().is_some() {
        bail!(
            "-o {}: the directory is not empty (nothing was written)",
            args.out.display()
        );
    }
    let mut files = Vec::new();
    for (m, f) in materials.iter().zip(&fractions) {
        files.push(write(&args.out, &format!("{}.npy", m.name()), f)?);
    }
    let mut vmi_report = Vec::new();
    for (&kev, v) in args.kev.iter().zip(&vmis) {
        vmi_report.push(Vmi {
            kev,
            file: write(&args.out, &format!("vmi-{kev}keV.npy"), v)?,
            extrapolated: lo.is_none_or(|lo| kev < lo) || hi.is_none_or(|hi| kev > hi),
        });
    }
    let report = Report {
        run_dir: args.run_dir.display().to_string(),
        basis: materials.iter().map(|m| m.name()).collect(),
        fractions: files,
        channels: scene
            .channels
            .iter()
            .map(|c| c.label.clone())
            .zip(specs)
            .collect(),
        spectra_exact: exact,
        matrix: d.matrix().to_vec(),
        condition: d.separability.condition,
        noise_gain: d.separability.noise_gain.clone(),
        vmi: vmi_report,
        against_references,
    };
    let path = args.out.join("decomposition.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", path.display()))?;
    eprintln!(
        "{} basis fractions ({}) and {} VMI(s) → {} (condition number {:.1})",
        materials.len(),
        report.basis.join(", "),
        args.kev.len(),
        args.out.display(),
        d.separability.condition
    );
    if let Some(s) = &report.against_references {
        for (m, r) in report.basis.iter().zip(&s.fraction_rmse) {
            eprintln!("  {m}: fraction RMSE {r:.3e} against the references' decomposition");
        }
        for (k, p) in args.kev.iter().zip(&s.vmi_psnr) {
            eprintln!("  VMI {k} keV: PSNR {p:.2} dB");
        }
    }
    Ok(())
}

/// Write `a` as `<dir>/<name>`; the file name.
fn write(dir: &Path, name: &str, a: &Array3<f32>) -> anyhow::Result<String> {
    let path = dir.join(name);
    ndarray_npy::write_npy(&path, a).with_context(|| format!("writing {}", path.display()))?;
    Ok(name.to_string())
}

fn read_volume(path: &Path) -> anyhow::Result<Array3<f32>> {
    ndarray_npy::read_npy(path).with_context(|| format!("reading the volume {}", path.display()))
}

/// The lowest and highest energy of the mono channels (None when there are none).
fn mono_range(specs: &[ChannelSpec]) -> (Option<f64>, Option<f64>) {
    let kevs: Vec<f64> = specs
        .iter()
        .filter_map(|s| match s {
            ChannelSpec::Mono { kev } => Some(*kev),
            _ => None,
        })
        .collect();
    (
        kevs.iter().copied().reduce(f64::min),
        kevs.iter().copied().reduce(f64::max),
    )
}
