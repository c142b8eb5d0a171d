//! `prism query <run_dir> (--coordinate X | --tau T) -o out.npy [--projections]`: the volume
//! (or the projections at every view of the run's geometry) of a trained spectral model
//! (`4dsg`, `4dsg-stage1`) at any point of the spectral axis, without further optimisation.

use prism_recon::gaussian::cpu_device;
use prism_recon::pipeline::RunDir;
use prism_recon::query::{Query, QueryAt};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Run directory of a spectral method (holds gaussians.safetensors).
    run_dir: PathBuf,
    /// Spectral coordinate in the scene's unit (keV, kVp, λ…), mapped to τ like the channels.
    #[arg(long, conflicts_with = "tau", required_unless_present = "tau")]
    coordinate: Option<f64>,
    /// Normalised spectral coordinate τ (0 and 1 are the scene's first and last channel).
    #[arg(long)]
    tau: Option<f64>,
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
    let q = Query::open(&RunDir::spectral_model(&args.run_dir)?, &cpu_device())?;
    let at = match (args.coordinate, args.tau) {
        (Some(c), _) => QueryAt::Coordinate(c),
        (None, Some(t)) => QueryAt::Tau(t),
        (None, None) => anyhow::bail!("give --coordinate or --tau"),
    };
    let data = if args.projections {
        q.projections(at, args.extrapolate)?
    } else {
        q.volume(at, args.extrapolate)?
    };
    ndarray_npy::write_npy(&args.out, &data)
        .map_err(|e| anyhow::anyhow!("{}: writing failed: {e}", args.out.display()))?;
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
