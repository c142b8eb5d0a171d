//! `prism`: simulate, inspect and reconstruct sparse-view spectral CT scenes.
//!
//! Each subcommand lives in its own module and only parses arguments, reports progress and calls
//! `prism-core`; no algorithm lives here.

mod ablate;
mod bench;
mod info;
mod query;
mod recon;
mod report;
mod simulate;

use clap::{Parser, Subcommand};

/// jemalloc instead of the system allocator: training allocates and frees tensors of tens of MB
/// every iteration, which glibc returns to the OS each time (its mmap threshold), so every step
/// paid page faults (10–30 % of a GSC-Net step measured with `perf`).
#[cfg(not(target_env = "msvc"))]
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

/// jemalloc's options for this binary: freed pages are kept for reuse instead of being purged
/// on jemalloc's decay clock (sys time of an r2gs run on chest-40, one thread: 6.7 → 3.2 s of
/// 26 s; peak RSS +20 %, since memory stays at its high-water mark). The environment variable
/// `_RJEM_MALLOC_CONF` still overrides it.
#[cfg(not(target_env = "msvc"))]
#[unsafe(export_name = "_rjem_malloc_conf")]
#[used]
static JEMALLOC_CONF: ConfString = ConfString(c"dirty_decay_ms:-1,muzzy_decay_ms:-1".as_ptr());

/// A C `const char *` (jemalloc reads `malloc_conf` as one).
#[cfg(not(target_env = "msvc"))]
#[repr(transparent)]
struct ConfString(*const std::ffi::c_char);

// SAFETY: it points at an immutable `'static` string.
#[cfg(not(target_env = "msvc"))]
unsafe impl Sync for ConfString {}
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "prism", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a spectral scene from a config (configs/*.yaml) into a scene directory.
    Simulate(simulate::Args),
    /// Print a scene's geometry, channels, availability and value ranges.
    Info(info::Args),
    /// Reconstruct every channel (fdk | sart | cgls | r2gs | 4dsg-stage1 | 4dsg) into a run directory.
    Recon(recon::ReconArgs),
    /// Volume or projections of a trained spectral model at any spectral coordinate.
    Query(query::Args),
    /// Per-channel PSNR/SSIM table of finished runs, with the paths of their volumes.
    Report(report::Args),
    /// 4D-SG stage-2 ablations (freezing strategies, GSC-Net vs MLP) from one shared stage 1.
    Ablate(ablate::Args),
    /// Benchmarks that print one JSON object (`prism bench classic`).
    Bench(bench::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate(args) => simulate::run(args),
        Command::Info(args) => info::run(args),
        Command::Recon(args) => recon::run(args),
        Command::Query(args) => query::run(args),
        Command::Report(args) => report::run(args),
        Command::Ablate(args) => ablate::run(args),
        Command::Bench(args) => bench::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
