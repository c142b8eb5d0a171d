//! `prism decompose <run_dir> -s <scene_dir> -o <out_dir> [--basis …] [--kev …] [--image-domain]`:
//! basis-material fractions and virtual monoenergetic images of a run
//! ([`prism_recon::decompose`]); prints what was written and the scores.

use crate::progress::Bars;
use prism_recon::decompose::{Request, decompose};
use std::path::PathBuf;

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

pub fn run(args: Args) -> anyhow::Result<()> {
    let request = Request {
        run_dir: args.run_dir,
        scene_dir: args.scene,
        out: args.out,
        basis: args.basis,
        image_domain: args.image_domain,
        kev: args.kev,
    };
    let report = decompose(&request, &Bars::new())?;
    eprintln!(
        "{} basis fractions ({}, from the {}) and {} VMI(s) → {} (condition number {:.1})",
        report.basis.len(),
        report.basis.join(", "),
        if report.source == "gaussians" {
            "run's basis Gaussians"
        } else {
            "channel volumes"
        },
        report.vmi.len(),
        request.out.display(),
        report.condition
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
            for (v, p) in report.vmi.iter().zip(&s.vmi_psnr) {
                eprintln!("    VMI {} keV: PSNR {p:.2} dB", v.kev);
            }
        }
    }
    Ok(())
}
