//! `prism decompose <run_dir> -s <scene_dir> -o <out_dir> [--basis …] [--kev …] [--image-domain]`:
//! basis-material fractions and virtual monoenergetic images of a run. A run trained with the
//! basis head (`stage2.basis`) has them in its Gaussians (`basis.safetensors`), which are
//! voxelized; any other run (or `--image-domain`, or another `--basis`) is decomposed from its
//! channel volumes (the image-domain step of a two-step decomposition; see
//! `prism_domain::decompose`).

use anyhow::{Context, bail};
use ndarray::Array3;
use prism_domain::decompose::{
    Basis, Decomposition, basis_truth, channel_specs, extrapolates, true_vmi, vmi,
};
use prism_domain::metrics::psnr::psnr;
use prism_domain::physics::{ChannelSpec, Material};
use prism_domain::scene::Scene;
use prism_recon::gaussian::cpu_device;
use prism_recon::pipeline::RunDir;
use prism_recon::query::BasisModel;
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
    /// Basis materials, comma-separated (1 to 4 of the attenuation table's); default: a basis
    /// run's own, else water,cortical_bone,iodine.
    #[arg(long, value_delimiter = ',')]
    basis: Option<Vec<String>>,
    /// Decompose the channel volumes even when the run carries basis Gaussians.
    #[arg(long)]
    image_domain: bool,
    /// Energies (keV, 10–150) of virtual monoenergetic images to write, comma-separated.
    #[arg(long, value_delimiter = ',')]
    kev: Vec<f64>,
}

/// `decomposition.json`.
#[derive(Serialize)]
struct Report {
    run_dir: String,
    /// Where the fractions come from: `gaussians` (the run's basis head) or `image` (NNLS of
    /// the channel volumes, voxel by voxel).
    source: &'static str,
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
    /// Against the decomposition of the scene's reference volumes (the reconstruction's error
    /// alone), inside the body (voxels where any reference exceeds 1 % of its maximum).
    against_references: Option<Scores>,
    /// Against the simulated object's material fractions, spread over the basis by their
    /// equivalents over `energies_kev`, and its true monoenergetic images (the basis model's
    /// error included).
    against_truth: Option<Scores>,
}

#[derive(Serialize)]
struct Vmi {
    kev: f64,
    file: String,
    /// The simulated object's true monoenergetic image (to score any other method's image).
    #[serde(skip_serializing_if = "Option::is_none")]
    truth: Option<String>,
    /// Outside the channels' energies: an extrapolation of the basis model.
    extrapolated: bool,
}

#[derive(Serialize)]
struct Scores {
    #[serde(skip_serializing_if = "Option::is_none")]
    energies_kev: Option<[f64; 2]>,
    voxels: usize,
    /// Per basis material: RMSE of the fraction.
    fraction_rmse: Vec<f64>,
    /// Per VMI energy: PSNR (dB, peak = the reference VMI's maximum) over the whole volume.
    vmi_psnr: Vec<f64>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.out.is_dir() && std::fs::read_dir(&args.out)?.next().is_some() {
        bail!(
            "-o {}: the directory is not empty (nothing was written)",
            args.out.display()
        );
    }
    let run_basis = BasisModel::open(&args.run_dir.join(RunDir::MODEL), &cpu_device())?;
    let materials = match (&args.basis, &run_basis) {
        (Some(names), _) => names
            .iter()
            .map(|n| Material::from_name(n.trim()))
            .collect::<Result<Vec<_>, _>>()?,
        (None, Some(b)) => b.meta.materials.clone(),
        (None, None) => Basis::body().materials().to_vec(),
    };
    let basis = Basis::new(&materials)?;
    let gaussian = run_basis.filter(|b| !args.image_domain && b.meta.materials == materials);
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
    let shape = scene.geometry.volume.shape_zyx();
    let fractions = match &gaussian {
        Some(b) => {
            let f = b.fractions()?;
            if f[0].shape() != shape {
                bail!(
                    "{}: the run's grid {:?} is not the scene's {shape:?}",
                    args.run_dir.display(),
                    f[0].shape()
                );
            }
            f
        }
        None => {
            let volumes = scene
                .channels
                .iter()
                .map(|ch| read_volume(&args.run_dir.join(RunDir::volume_file(&ch.label)), shape))
                .collect::<anyhow::Result<Vec<_>>>()?;
            let views: Vec<_> = volumes.iter().map(|v| v.view()).collect();
            d.volumes(&views)?
        }
    };
    let (lo, hi) = mono_range(&specs);
    let centres = specs
        .iter()
        .map(ChannelSpec::mean_kev)
        .collect::<Result<Vec<_>, _>>()?;
    let outside = |e: f64| extrapolates(&centres, e);
    for &e in &args.kev {
        prism_domain::physics::attenuation::check_energy(e, "--kev")?;
        if outside(e) {
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
    // Scored inside the body: voxels where any reference exceeds 1 % of the largest value.
    let (mut against_references, mut against_truth, mut true_vmis) = (None, None, Vec::new());
    if let Some(r) = &scene.references {
        let refs: Vec<_> = r.outer_iter().collect();
        let peak = r.iter().fold(0.0f32, |a, &v| a.max(v));
        let mut body = Array3::from_elem(refs[0].dim(), false);
        for v in &refs {
            ndarray::Zip::from(&mut body)
                .and(v)
                .for_each(|b, &x| *b |= x > 0.01 * peak);
        }
        let truth = d.volumes(&refs)?;
        let truth_vmis = args
            .kev
            .iter()
            .map(|&e| vmi(&basis, &truth, e))
            .collect::<Result<Vec<_>, _>>()?;
        against_references = Some(score(&fractions, &vmis, &truth, &truth_vmis, &body)?);
        if let Some(maps) = &scene.materials {
            let energies: Vec<f64> = match (lo, hi) {
                (Some(lo), Some(hi)) if hi > lo => {
                    (0..=((hi - lo) as usize)).map(|i| lo + i as f64).collect()
                }
                _ => (20..=120).map(f64::from).collect(),
            };
            let truth = basis_truth(maps, &basis, &energies)?;
            let truth_vmis = args
                .kev
                .iter()
                .map(|&e| true_vmi(maps, e))
                .collect::<Result<Vec<_>, _>>()?;
            let mut s = score(&fractions, &vmis, &truth, &truth_vmis, &body)?;
            s.energies_kev = Some([energies[0], energies[energies.len() - 1]]);
            against_truth = Some(s);
            true_vmis = truth_vmis;
        }
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut files = Vec::new();
    for (m, f) in materials.iter().zip(&fractions) {
        files.push(write(&args.out, &format!("{}.npy", m.name()), f)?);
    }
    let mut vmi_report = Vec::new();
    for (i, (&kev, v)) in args.kev.iter().zip(&vmis).enumerate() {
        vmi_report.push(Vmi {
            kev,
            file: write(&args.out, &format!("vmi-{kev}keV.npy"), v)?,
            truth: true_vmis
                .get(i)
                .map(|t| write(&args.out, &format!("vmi-{kev}keV.truth.npy"), t))
                .transpose()?,
            extrapolated: outside(kev),
        });
    }
    let report = Report {
        run_dir: args.run_dir.display().to_string(),
        source: if gaussian.is_some() {
            "gaussians"
        } else {
            "image"
        },
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
        against_truth,
    };
    let path = args.out.join("decomposition.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", path.display()))?;
    eprintln!(
        "{} basis fractions ({}, from the {}) and {} VMI(s) → {} (condition number {:.1})",
        materials.len(),
        report.basis.join(", "),
        if gaussian.is_some() {
            "run's basis Gaussians"
        } else {
            "channel volumes"
        },
        args.kev.len(),
        args.out.display(),
        d.separability.condition
    );
    for (what, s) in [
        ("the references' decomposition", &report.against_references),
        ("the true material fractions", &report.against_truth),
    ] {
        if let Some(s) = s {
            eprintln!("  against {what}:");
            for (m, r) in report.basis.iter().zip(&s.fraction_rmse) {
                eprintln!("    {m}: fraction RMSE {r:.3e}");
            }
            for (k, p) in args.kev.iter().zip(&s.vmi_psnr) {
                eprintln!("    VMI {k} keV: PSNR {p:.2} dB");
            }
        }
    }
    Ok(())
}

/// Fraction RMSE per basis material inside `body` and VMI PSNR (peak: the truth's maximum).
fn score(
    fractions: &[Array3<f32>],
    vmis: &[Array3<f32>],
    truth: &[Array3<f32>],
    truth_vmis: &[Array3<f32>],
    body: &Array3<bool>,
) -> anyhow::Result<Scores> {
    let voxels = body.iter().filter(|&&b| b).count().max(1);
    let fraction_rmse = fractions
        .iter()
        .zip(truth)
        .map(|(f, t)| {
            let se = ndarray::Zip::from(f)
                .and(t)
                .and(body)
                .fold(0.0f64, |a, &f, &t, &b| {
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
        .zip(truth_vmis)
        .map(|(v, t)| {
            let peak = t.iter().fold(0.0f32, |a, &x| a.max(x)) as f64;
            psnr(v.view(), t.view(), peak)
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Scores {
        energies_kev: None,
        voxels,
        fraction_rmse,
        vmi_psnr,
    })
}

/// Write `a` as `<dir>/<name>`; the file name.
fn write(dir: &Path, name: &str, a: &Array3<f32>) -> anyhow::Result<String> {
    let path = dir.join(name);
    ndarray_npy::write_npy(&path, a).with_context(|| format!("writing {}", path.display()))?;
    Ok(name.to_string())
}

/// A run's channel volume, which must lie on the scene's grid (`shape`, `[z][y][x]`) and be
/// finite.
fn read_volume(path: &Path, shape: [usize; 3]) -> anyhow::Result<Array3<f32>> {
    let v: Array3<f32> = ndarray_npy::read_npy(path)
        .with_context(|| format!("reading the volume {}", path.display()))?;
    if v.shape() != shape {
        bail!(
            "{}: shape {:?}, the scene's grid is {shape:?}",
            path.display(),
            v.shape()
        );
    }
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        bail!("{}: value {i} (row-major) is not finite", path.display());
    }
    Ok(v)
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
