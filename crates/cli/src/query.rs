//! `prism query <run_dir> (--coordinate X | --tau T | --kev E) -o out.npy [--projections]`: the
//! volume (or the projections at every view of the run's geometry) of a trained spectral model
//! (`4dsg`, `4dsg-stage1`) at any point of the spectral axis, without further optimisation.
//! `--kev` asks for a virtual monoenergetic image: from a basis-head run (`stage2.basis`) at any
//! energy of the attenuation table, with a warning outside the trained channels' energies; from
//! a curve run whose channels are energies, the curve query at that energy.

use ndarray::Array3;
use prism_domain::memory::{self, Footprint};
use prism_domain::scene::npy::npy_bytes;
use prism_domain::staged;
use prism_recon::device::cpu_device;
use prism_recon::gaussians::io::LoadedModel;
use prism_recon::methods::fourdsg::query::{Ask, SpectralModel};
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
    /// Replace the output file when it exists.
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    memory: crate::args::MemoryArgs,
}

/// The query's peak memory: the model as loaded, the output array and its file's bytes.
fn footprint(loaded: &LoadedModel, projections: bool) -> anyhow::Result<Footprint> {
    let g = &loaded.info.geometry;
    let (what, n) = if projections {
        let dims = [g.views(), g.detector.rows, g.detector.cols];
        ("projections", memory::elements("geometry.detector", &dims)?)
    } else {
        let v = &g.volume;
        (
            "volume",
            memory::elements("geometry.volume", &[v.nz, v.ny, v.nx])?,
        )
    };
    let k = loaded.model.len();
    let columns = 10 + loaded.info.channels.len();
    let mut f = Footprint::process();
    f.add(
        format!("the model ({k} Gaussians, host and device copies)"),
        memory::bytes(k, 4 * columns * 3),
    );
    f.add(
        format!("the {what} rendered, its accumulator and its file ({n} values)"),
        memory::bytes(n, 12),
    );
    Ok(f)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let path = RunDir::spectral_model(&args.run_dir)?;
    let what = format!("querying {}", args.run_dir.display());
    let ask = match (args.coordinate, args.tau, args.kev) {
        (Some(c), _, _) => Ask::Coordinate(c),
        (None, Some(t), _) => Ask::Tau(t),
        (None, None, Some(kev)) => Ask::Kev(kev),
        (None, None, None) => anyhow::bail!("give --coordinate, --tau or --kev"),
    };
    let model = SpectralModel::open(&path, ask, &cpu_device())?;
    if !args
        .memory
        .proceed(&path, &what, &footprint(model.loaded(), args.projections)?)?
    {
        return Ok(());
    }
    let answer = model.answer(ask, args.projections, args.extrapolate)?;
    write(&args.out, &answer.data, args.force)?;
    if let Some(w) = &answer.warning {
        eprintln!("warning: {w}");
    }
    eprintln!(
        "{} → {} {:?}",
        answer.summary,
        args.out.display(),
        answer.data.dim()
    );
    Ok(())
}

/// Write the output atomically (a full disk leaves no partial file); an existing file only
/// with `--force`.
fn write(out: &Path, data: &Array3<f32>, force: bool) -> anyhow::Result<()> {
    Ok(staged::publish_file(out, &npy_bytes(data)?, force)?)
}
