//! `prism query <run_dir> (--coordinate X | --tau T | --kev E) -o out.npy [--projections]`: the
//! volume (or the projections at every view of the run's geometry) of a trained spectral model
//! (`4dsg`, `4dsg-stage1`) at any point of the spectral axis, without further optimisation.
//! `--kev` asks for a virtual monoenergetic image: from a basis-head run (`stage2.basis`) at any
//! energy of the attenuation table, with a warning outside the trained channels' energies; from
//! a curve run whose channels are energies, the curve query at that energy.

use ndarray::Array3;
use prism_recon::device::cpu_device;
use prism_recon::methods::fourdsg::query::BasisModel;
use prism_recon::methods::fourdsg::query::{Query, QueryAt};
use prism_recon::record::RunDir;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// Run directory of a spectral method (holds gaussians.safetensors).
    run_dir: PathBuf,
    /// Spectral coordinate in the scene's unit (keV, kVp, λ…), mapped to τ like the channels.
    #[arg(long, conflicts_with_all = ["tau", "kev"], required_unless_present_any = ["tau", "kev"])]
    coordinate: Option<f64>,
    /// Normalised spectral coordinate τ (0 and 1 are the scene's first and last channel).
    #[arg(long, conflicts_with = "kev")]
    tau: Option<f64>,
    /// Photon energy (keV, 10–150) of a virtual monoenergetic image (see the module docs).
    #[arg(long)]
    kev: Option<f64>,
    /// Output .npy: a volume `[z][y][x]` in mm⁻¹, or with --projections line integrals
    /// `[view][row][col]`.
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// Render the projections at every view of the run's geometry instead of the volume.
    #[arg(long)]
    projections: bool,
    /// Allow τ outside the observed grid (linear extension of the end segments).
    #[arg(long)]
    extrapolate: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let path = RunDir::spectral_model(&args.run_dir)?;
    if let Some(kev) = args.kev
        && let Some(b) = BasisModel::open(&path, &cpu_device())?
    {
        let data = if args.projections {
            b.vmi_projections(kev)?
        } else {
            b.vmi(kev)?
        };
        write(&args.out, &data)?;
        if b.extrapolates(kev) {
            eprintln!(
                "warning: {kev} keV lies outside the trained channels' energies ({:?} keV): the \
                 image extrapolates the basis model, whose error grows with the distance",
                b.meta.channel_kev
            );
        }
        let names: Vec<&str> = b.meta.materials.iter().map(|m| m.name()).collect();
        eprintln!(
            "{kev} keV from the basis {} → {} {:?}",
            names.join(", "),
            args.out.display(),
            data.dim()
        );
        return Ok(());
    }
    let q = Query::open(&path, &cpu_device())?;
    let at = match (args.coordinate, args.tau, args.kev) {
        (Some(c), _, _) => QueryAt::Coordinate(c),
        (None, Some(t), _) => QueryAt::Tau(t),
        (None, None, Some(kev)) => {
            if !q.loaded.info.monoenergetic {
                anyhow::bail!(
                    "--kev {kev}: this run has no basis head and its channels are not all \
                     monoenergetic (axis in {}), so no coordinate is a photon energy; train with \
                     stage2.basis for monoenergetic images, or query --coordinate",
                    q.loaded.info.unit
                );
            }
            QueryAt::Coordinate(kev)
        }
        (None, None, None) => anyhow::bail!("give --coordinate, --tau or --kev"),
    };
    let data = if args.projections {
        q.projections(at, args.extrapolate)?
    } else {
        q.volume(at, args.extrapolate)?
    };
    write(&args.out, &data)?;
    let info = &q.loaded.info;
    eprintln!(
        "τ = {:.4} (observed: {}) → {} {:?}",
        q.tau(at),
        info.channels
            .iter()
            .zip(&info.tau)
            .map(|(l, t)| format!("{l} τ={t:.3}"))
            .collect::<Vec<_>>()
            .join(", "),
        args.out.display(),
        data.dim()
    );
    Ok(())
}

fn write(out: &Path, data: &Array3<f32>) -> anyhow::Result<()> {
    ndarray_npy::write_npy(out, data)
        .map_err(|e| anyhow::anyhow!("{}: writing failed: {e}", out.display()))
}
