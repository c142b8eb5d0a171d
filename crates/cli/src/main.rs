//! `prism`: simulate, inspect and reconstruct sparse-view spectral CT scenes.
//!
//! Each subcommand lives in its own module and only parses arguments, shows progress
//! ([`progress::Bars`]) and calls `prism-domain` or `prism-recon`; no algorithm lives here.

mod ablate;
#[cfg(not(target_env = "msvc"))]
mod alloc;
mod args;
mod axis;
mod bench;
mod decompose;
mod experiment;
mod export;
mod import;
mod info;
mod interrupt;
mod progress;
mod query;
mod recon;
mod report;
mod simulate;

use clap::{Parser, Subcommand};

/// jemalloc instead of the system allocator: training allocates and frees tensors of tens of MB
/// every iteration, which glibc returns to the OS each time (its mmap threshold), so every step
/// paid page faults; jemalloc keeps freed pages for reuse (decay of seconds).
#[cfg(not(target_env = "msvc"))]
#[global_allocator]
static ALLOCATOR: alloc::Counting = alloc::Counting;

/// jemalloc's options, read at start-up (`_RJEM_MALLOC_CONF` in the environment still wins).
/// `thp:always`: jemalloc zeroes a recycled extent for `calloc` (every `zeros` tensor and array)
/// with `madvise(MADV_DONTNEED)` unless transparent huge pages are requested, in which case it
/// uses `memset`; the madvise path made every zeroed buffer fault its pages in again (8.9 million
/// minor faults and 29 s of system time in a 77 s R²-Gaussian run; with `thp:always`: 0.18
/// million and 3.6 s, wall 48 s, identical results).
/// `dirty_decay_ms:1000,muzzy_decay_ms:-1`: freed pages are not handed back to the kernel
/// (`MADV_DONTNEED`, after jemalloc's default 10 s decay) but, after 1 s, marked lazily freeable
/// (`MADV_FREE`): the kernel takes them only under memory pressure, and a page written again
/// before that costs no fault. A training step frees and reallocates the same tensor sizes every
/// iteration (Burn does not pool CPU tensors), and with the default decay those pages went back
/// and faulted in again: the main job (`scripts/main-job.sh`) spent 8.4 % of its user time in the
/// kernel with 1.95 million faults; with this setting 3.2 % and 19 thousand faults, peak resident
/// size 185 MB instead of 172 MB, identical results. Never purging (`dirty_decay_ms:-1`) saves as
/// much but doubled the peak resident size (375 MB): pages freed as the Gaussian count grows stay
/// dirty.
#[cfg(not(target_env = "msvc"))]
#[allow(non_upper_case_globals)]
#[unsafe(export_name = "_rjem_malloc_conf")]
pub static malloc_conf: Option<&'static u8> =
    Some(&b"thp:always,dirty_decay_ms:1000,muzzy_decay_ms:-1\0"[0]);
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
    /// Reconstruct every channel (fdk | sart | cgls | tv | naf | r2gs | 4dsg-stage1 | 4dsg) into a run directory.
    Recon(recon::ReconArgs),
    /// Volume or projections of a trained spectral model at any spectral coordinate.
    Query(query::Args),
    /// Basis-material fractions (water, bone, iodine, …) and virtual monoenergetic images from
    /// a run's channel volumes.
    Decompose(decompose::Args),
    /// Per-channel PSNR/SSIM table of finished runs, with the paths of their volumes.
    Report(report::Args),
    /// 4D-SG stage-2 ablations (freezing strategies, GSC-Net vs MLP) from one shared stage 1.
    Ablate(ablate::Args),
    /// Benchmarks that print one JSON object (`prism bench classic`).
    Bench(bench::Args),
    /// An experiment suite (configs/suites/): methods × scenes × views × noise × seeds, resumable,
    /// with results.csv, a report in the paper's table layout and figures; `--slurm` for clusters.
    Experiment(experiment::Args),
    /// Measured projections (counts with flat and dark fields, or line integrals; .npy, TIFF,
    /// raw) of one or several acquisitions into a scene, with the full-view FDK as reference.
    Import(import::Args),
    /// A scan's rotation axis estimated from its projections (opposing views on a full turn,
    /// sharpness otherwise), with `--scan` the estimators' scores over a range of offsets.
    Axis(axis::Args),
    /// Volumes (a scene's references, `prism recon` / `prism query` output) as NIfTI-1 (.nii,
    /// .nii.gz) or MetaImage (.mha) with the scene's voxel spacing and grid position, or TIFF stacks.
    Export(export::Args),
}

/// Every command runs on a worker of the CPU's pool ([`prism_recon::device::on_cpu_workers`]).
fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = prism_recon::device::on_cpu_workers(|| run(cli));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", describe(&e));
            // 128 + SIGINT, as a shell reports a process ended by Ctrl-C.
            match e.downcast_ref::<prism_recon::Error>() {
                Some(prism_recon::Error::Interrupted { .. }) => ExitCode::from(130),
                _ => ExitCode::FAILURE,
            }
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Simulate(args) => simulate::run(args),
        Command::Info(args) => info::run(args),
        Command::Recon(args) => recon::run_cmd(args),
        Command::Query(args) => query::run(args),
        Command::Decompose(args) => decompose::run(args),
        Command::Report(args) => report::run(args),
        Command::Ablate(args) => ablate::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Experiment(args) => experiment::run(args),
        Command::Export(args) => export::run(args),
        Command::Import(args) => import::run(args),
        Command::Axis(args) => axis::run(args),
    }
}

/// An error and its causes, each once: Prism's errors already include their source's message
/// (`path: No such file or directory`), which `{:#}` would print a second time.
fn describe(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let s = cause.to_string();
        if !out.contains(&s) {
            if !out.is_empty() {
                out.push_str(": ");
            }
            out.push_str(&s);
        }
    }
    out
}
