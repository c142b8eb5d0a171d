//! Basis-material decomposition of a finished run (`prism decompose`): volume fractions of 1–4
//! basis materials and virtual monoenergetic images (VMIs), scored against the scene's
//! references and, for a simulated scene, its true material fractions.
//!
//! A run trained with the basis head (`stage2.basis`) carries the fractions in its Gaussians
//! (`basis.safetensors`), which are voxelized; any other run (or [`Request::image_domain`], or
//! another basis) is decomposed from its channel volumes, voxel by voxel (the image-domain step
//! of a two-step decomposition; the math is `prism_domain::decompose`). Writes
//! `<material>.npy`, `vmi-<E>keV.npy` (and `vmi-<E>keV.truth.npy` for a simulated scene) and
//! `decomposition.json` ([`Report`]).

use crate::device::cpu_device;
use crate::methods::fourdsg::query::BasisModel;
use crate::record::RunDir;
use crate::{Error, Result};
use ndarray::Array3;
use prism_domain::decompose::{
    Basis, Decomposition, basis_truth, channel_specs, extrapolates, true_vmi, vmi,
};
use prism_domain::metrics::psnr::psnr;
use prism_domain::observe::{Level, Observer};
use prism_domain::physics::{ChannelSpec, Material};
use prism_domain::scene::Scene;
use prism_domain::scene::npy::npy_bytes;
use prism_domain::staged::{Staged, replace_file};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// What to decompose, and where to write it.
#[derive(Clone, Debug)]
pub struct Request {
    /// Run directory holding one `<label>.npy` volume (mm⁻¹) per channel of the scene.
    pub run_dir: PathBuf,
    /// The scene the run reconstructed (its channels' spectra; its references, if any, are
    /// decomposed too and the run is scored against them).
    pub scene_dir: PathBuf,
    /// Output directory (created; must not exist or be empty).
    pub out: PathBuf,
    /// Basis materials by name (1 to 4 of the attenuation table's); `None`: a basis run's own,
    /// else water, cortical bone and iodine.
    pub basis: Option<Vec<String>>,
    /// Decompose the channel volumes even when the run carries basis Gaussians.
    pub image_domain: bool,
    /// Energies (keV, 10–150) of the VMIs to write.
    pub kev: Vec<f64>,
}

/// `decomposition.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub run_dir: String,
    /// Where the fractions come from: `gaussians` (the run's basis head) or `image` (NNLS of
    /// the channel volumes, voxel by voxel).
    pub source: &'static str,
    pub basis: Vec<&'static str>,
    /// The fraction files: volume fraction of each basis material at its nominal density.
    pub fractions: Vec<String>,
    /// How each channel's basis attenuation was computed, and whether it is the scene's own.
    pub channels: Vec<(String, ChannelSpec)>,
    pub spectra_exact: bool,
    /// `[channel][basis]`, mm⁻¹.
    pub matrix: Vec<Vec<f64>>,
    pub condition: f64,
    /// Standard deviation of each fraction per mm⁻¹ of channel-volume noise.
    pub noise_gain: Vec<f64>,
    pub vmi: Vec<Vmi>,
    /// Against the decomposition of the scene's reference volumes (the reconstruction's error
    /// alone), inside the body (voxels where any reference exceeds 1 % of its maximum).
    pub against_references: Option<Scores>,
    /// Against the simulated object's material fractions, spread over the basis by their
    /// equivalents over `energies_kev`, and its true monoenergetic images (the basis model's
    /// error included).
    pub against_truth: Option<Scores>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Vmi {
    pub kev: f64,
    pub file: String,
    /// The simulated object's true monoenergetic image (to score any other method's image).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truth: Option<String>,
    /// Outside the channels' energies: an extrapolation of the basis model.
    pub extrapolated: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct Scores {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub energies_kev: Option<[f64; 2]>,
    pub voxels: usize,
    /// Per basis material: RMSE of the fraction.
    pub fraction_rmse: Vec<f64>,
    /// Per VMI energy: PSNR (dB, peak = the reference VMI's maximum) over the whole volume.
    pub vmi_psnr: Vec<f64>,
}

/// File name of the report in the output directory.
pub const REPORT_FILE: &str = "decomposition.json";

/// Decompose the run of `request` and write its maps, VMIs and [`REPORT_FILE`]; warnings (spectra
/// taken with the default filtration, extrapolated VMIs) go to `observer`. Nothing is written
/// when the request is refused (a non-empty output, a basis the channels cannot separate, a
/// volume off the scene's grid or not finite).
pub fn decompose(request: &Request, observer: &dyn Observer) -> Result<Report> {
    let out = &request.out;
    let not_empty = out.is_dir()
        && std::fs::read_dir(out)
            .map_err(|e| Error::io(out, e))?
            .next()
            .is_some();
    if not_empty {
        return Err(Error::invalid(
            "-o",
            format!(
                "{}: the directory is not empty (nothing was written)",
                out.display()
            ),
        ));
    }
    // Written beside `out` and published by rename: a second decompose into the same directory
    // while this one runs is refused, and a failure (a full disk) leaves nothing behind.
    let staged = Staged::create(out)?;
    let dir = staged.path();
    let run_basis = BasisModel::open(&request.run_dir.join(RunDir::MODEL), &cpu_device())?;
    let materials = match (&request.basis, &run_basis) {
        (Some(names), _) => names
            .iter()
            .map(|n| Material::from_name(n.trim()))
            .collect::<std::result::Result<Vec<_>, _>>()?,
        (None, Some(b)) => b.meta.materials.clone(),
        (None, None) => Basis::body().materials().to_vec(),
    };
    let basis = Basis::new(&materials)?;
    let gaussian = run_basis.filter(|b| !request.image_domain && b.meta.materials == materials);
    let scene = Scene::load(&request.scene_dir)?;
    let (specs, exact) = channel_specs(&scene)?;
    if !exact {
        observer.note(
            Level::Warning,
            &format!(
                "{} records no channel spectra; tube voltages are taken with the default \
                 filtration",
                request.scene_dir.display()
            ),
        );
    }
    let d = Decomposition::new(basis.clone(), &specs)
        .map_err(|e| e.in_file(request.scene_dir.join("scene.yaml")))?;
    let shape = scene.geometry.volume.shape_zyx();
    let fractions = match &gaussian {
        Some(b) => {
            let f = b.fractions()?;
            if f[0].shape() != shape {
                return Err(Error::invalid(
                    "run_dir",
                    format!(
                        "{}: the run's grid {:?} is not the scene's {shape:?}",
                        request.run_dir.display(),
                        f[0].shape()
                    ),
                ));
            }
            f
        }
        None => {
            let volumes = scene
                .channels
                .iter()
                .map(|ch| read_volume(&request.run_dir.join(RunDir::volume_file(&ch.label)), shape))
                .collect::<Result<Vec<_>>>()?;
            let views: Vec<_> = volumes.iter().map(|v| v.view()).collect();
            d.volumes(&views)?
        }
    };
    let (lo, hi) = mono_range(&specs);
    let centres = specs
        .iter()
        .map(ChannelSpec::mean_kev)
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let outside = |e: f64| extrapolates(&centres, e);
    for &e in &request.kev {
        prism_domain::physics::attenuation::check_energy(e, "--kev")?;
        if outside(e) {
            observer.note(
                Level::Warning,
                &format!(
                    "{e} keV lies outside the channels' energies: its VMI extrapolates the \
                     basis model"
                ),
            );
        }
    }
    let vmis = request
        .kev
        .iter()
        .map(|&e| vmi(&basis, &fractions, e))
        .collect::<std::result::Result<Vec<_>, _>>()?;
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
        let truth_vmis = request
            .kev
            .iter()
            .map(|&e| vmi(&basis, &truth, e))
            .collect::<std::result::Result<Vec<_>, _>>()?;
        against_references = Some(score(&fractions, &vmis, &truth, &truth_vmis, &body)?);
        if let Some(maps) = &scene.materials {
            let energies: Vec<f64> = match (lo, hi) {
                (Some(lo), Some(hi)) if hi > lo => {
                    (0..=((hi - lo) as usize)).map(|i| lo + i as f64).collect()
                }
                _ => (20..=120).map(f64::from).collect(),
            };
            let truth = basis_truth(maps, &basis, &energies)?;
            let truth_vmis = request
                .kev
                .iter()
                .map(|&e| true_vmi(maps, e))
                .collect::<std::result::Result<Vec<_>, _>>()?;
            let mut s = score(&fractions, &vmis, &truth, &truth_vmis, &body)?;
            s.energies_kev = Some([energies[0], energies[energies.len() - 1]]);
            against_truth = Some(s);
            true_vmis = truth_vmis;
        }
    }
    let mut files = Vec::new();
    for (m, f) in materials.iter().zip(&fractions) {
        files.push(write(dir, &format!("{}.npy", m.name()), f)?);
    }
    let mut vmi_report = Vec::new();
    for (i, (&kev, v)) in request.kev.iter().zip(&vmis).enumerate() {
        vmi_report.push(Vmi {
            kev,
            file: write(dir, &format!("vmi-{kev}keV.npy"), v)?,
            truth: true_vmis
                .get(i)
                .map(|t| write(dir, &format!("vmi-{kev}keV.truth.npy"), t))
                .transpose()?,
            extrapolated: outside(kev),
        });
    }
    let report = Report {
        run_dir: request.run_dir.display().to_string(),
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
    let json = serde_json::to_string_pretty(&report)
        .map_err(|e| Error::invalid(REPORT_FILE, e.to_string()))?;
    replace_file(&dir.join(REPORT_FILE), json.as_bytes())?;
    // The output appears whole or not at all; it was empty or absent when the work began.
    staged.publish(|_| Ok(Default::default()))?;
    Ok(report)
}

/// Fraction RMSE per basis material inside `body` and VMI PSNR (peak: the truth's maximum).
fn score(
    fractions: &[Array3<f32>],
    vmis: &[Array3<f32>],
    truth: &[Array3<f32>],
    truth_vmis: &[Array3<f32>],
    body: &Array3<bool>,
) -> Result<Scores> {
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
        .collect::<std::result::Result<Vec<_>, _>>()?;
    Ok(Scores {
        energies_kev: None,
        voxels,
        fraction_rmse,
        vmi_psnr,
    })
}

/// Write `a` as `<dir>/<name>`, flushed; the file name.
fn write(dir: &Path, name: &str, a: &Array3<f32>) -> Result<String> {
    replace_file(&dir.join(name), &npy_bytes(a)?)?;
    Ok(name.to_string())
}

/// A run's channel volume, which must lie on the scene's grid (`shape`, `[z][y][x]`) and be
/// finite.
fn read_volume(path: &Path, shape: [usize; 3]) -> Result<Array3<f32>> {
    let file = path.display().to_string();
    let v: Array3<f32> = prism_domain::scene::npy::read_array(path, "volume")?;
    if v.shape() != shape {
        return Err(Error::invalid(
            &file,
            format!("shape {:?}, the scene's grid is {shape:?}", v.shape()),
        ));
    }
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(Error::invalid(
            &file,
            format!("value {i} (row-major) is not finite"),
        ));
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
