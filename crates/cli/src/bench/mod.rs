//! `prism bench`: benchmarks that print one JSON object on stdout.
//!
//! `classic`: the classic-CT benchmark (ours vs RTK in one run). RTK runs through `$PRISM_PYTHON`
//! (default `python3`) when `itk-rtk` is importable and is skipped with a message otherwise.
//! `iteration`: memory traffic of an R²-Gaussian training iteration ([`iteration`]).
//! `scaling`: iteration time and peak memory against the scene's size ([`scaling`]).

use crate::progress::Bars;
#[cfg(not(target_env = "msvc"))]
mod iteration;
#[cfg(not(target_env = "msvc"))]
mod probe;
#[cfg(not(target_env = "msvc"))]
mod scaling;

use prism_recon::methods::classic::bench::{BenchOptions, ordering, run as run_classic};

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    which: Which,
}

#[derive(clap::Subcommand)]
enum Which {
    /// Joseph FP/BP, FDK, SART, CGLS at 128³ / 256² / 50 views on the phantom, with RTK's side.
    Classic(ClassicArgs),
    /// Bytes an R²-Gaussian iteration allocates and must move, against the copy bandwidth.
    #[cfg(not(target_env = "msvc"))]
    Iteration(iteration::IterationArgs),
    /// Iteration time and peak memory of R²-Gaussian, 4D-SG and NAF against Gaussians, views,
    /// detector, grid and channels, with fitted power laws and log-log figures.
    #[cfg(not(target_env = "msvc"))]
    Scaling(scaling::ScalingArgs),
}

#[derive(clap::Args)]
struct ClassicArgs {
    /// 64³ / 128², no dense FDK, no 256³ error, no ordering check, one repeat.
    #[arg(long)]
    quick: bool,
    /// Skip RTK.
    #[arg(long)]
    no_rtk: bool,
    /// Skip the SART > CGLS > FDK check on phantom-3mono.
    #[arg(long)]
    no_ordering: bool,
    /// Skip the forward-projection error at 256³.
    #[arg(long)]
    no_256: bool,
    /// Only the speed comparison: no dense FDK, SART, CGLS, 256³ error or ordering check.
    #[arg(long)]
    speed_only: bool,
    /// Timed runs per operation on both sides (median reported, with min and max).
    #[arg(long, value_name = "N")]
    repeats: Option<usize>,
    /// Only the SART > CGLS > FDK check.
    #[arg(long)]
    ordering_only: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let a = match args.which {
        Which::Classic(a) => a,
        #[cfg(not(target_env = "msvc"))]
        Which::Iteration(a) => {
            let value = iteration::run_iteration(a)?;
            println!("{}", serde_json::to_string_pretty(&value)?);
            return Ok(());
        }
        #[cfg(not(target_env = "msvc"))]
        Which::Scaling(a) => return scaling::run(a),
    };
    let bars = Bars::new();
    let value = if a.ordering_only {
        ordering(&bars)?
    } else {
        let mut opts = BenchOptions::default();
        if a.quick {
            opts = BenchOptions {
                n: 64,
                det: 128,
                full_views: 0,
                fp_256: false,
                ordering: false,
                repeats: 1,
                ..opts
            };
        }
        if a.no_rtk {
            opts.python = None;
        }
        if a.no_ordering {
            opts.ordering = false;
        }
        if a.no_256 {
            opts.fp_256 = false;
        }
        if a.speed_only {
            opts = BenchOptions {
                full_views: 0,
                sart_epochs: 0,
                cgls_iterations: 0,
                fp_256: false,
                ordering: false,
                ..opts
            };
        }
        if let Some(n) = a.repeats {
            opts.repeats = n.max(1);
        }
        run_classic(&opts, &bars)?
    };
    bars.finish();
    println!("{}", serde_json::to_string_pretty(&value)?);
    Ok(())
}
