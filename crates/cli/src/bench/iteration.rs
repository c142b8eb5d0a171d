//! `prism bench iteration`: what one R²-Gaussian training iteration allocates, against what it
//! must move, and how far its time is from the memory-traffic bound.
//!
//! One run of an `r2gs` config on a scene, with no evaluation during training.
//! Over the last `--window` iterations of every stage (after densification, so the Gaussian count
//! `K` is fixed) it reads the allocator's counters ([`crate::alloc`]) and the clock at each
//! iteration. The bytes an iteration must move, with `P = 11` parameters per Gaussian (mean 3,
//! scale 3, rotation 4, density 1) in f32:
//! * the render reads the parameters (`4·P·K`), the backward writes their gradients (`4·P·K`),
//!   Adam reads parameters, gradients and both moments and writes parameters and moments
//!   (`28·P·K`);
//! * the view: the measured image read, the rendered image written and read (`12·rows·cols`);
//! * the TV patch: its voxels written and read (`8·s³`).
//!
//! Every allocated byte is written at least once, so the allocated bytes per iteration bound the
//! traffic of its fresh buffers from below. The machine's copy bandwidth (parallel copy of
//! 256 MiB, best of five, read + write bytes per second) turns the must-move bytes into the
//! iteration's traffic-bound time.

use super::probe::probed_run;
use crate::args::{EvalArgs, SetArgs};
use crate::progress::Bars;
use prism_domain::metrics::quantile;
use prism_domain::scene::Scene;
use prism_recon::MethodConfig;
use rayon::prelude::*;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Parameters per Gaussian of a one-column model (mean, scale, rotation, density).
const PARAMS: u64 = 11;

#[derive(clap::Args)]
pub struct IterationArgs {
    /// R²-Gaussian config (`method: r2gs`).
    #[arg(default_value = "configs/recon/r2gs.yaml")]
    config: PathBuf,
    /// Scene directory or R²-Gaussian case folder.
    #[arg(short = 's', long = "scene")]
    scene: PathBuf,
    /// Iterations measured at the end of every stage (after densification).
    #[arg(long, default_value_t = 200)]
    window: usize,
    #[command(flatten)]
    eval: EvalArgs,
    #[command(flatten)]
    set: SetArgs,
}

/// Copy bandwidth in bytes per second (read + write), best of five parallel 256 MiB copies.
fn copy_bandwidth() -> f64 {
    const LEN: usize = 1 << 26;
    let src: Vec<f32> = (0..LEN).map(|i| i as f32).collect();
    let mut dst = vec![0f32; LEN];
    let chunk = 1 << 16;
    (0..5)
        .map(|_| {
            let t = Instant::now();
            dst.par_chunks_mut(chunk)
                .zip(src.par_chunks(chunk))
                .for_each(|(d, s)| d.copy_from_slice(s));
            std::hint::black_box(&dst);
            (2 * 4 * LEN) as f64 / t.elapsed().as_secs_f64()
        })
        .fold(0.0, f64::max)
}

pub fn run_iteration(a: IterationArgs) -> anyhow::Result<serde_json::Value> {
    let mut config = MethodConfig::load_with(&a.config, &a.set.overrides()?)?;
    let MethodConfig::R2gs(r) = &mut config else {
        anyhow::bail!(
            "{}: method `{}`: `prism bench iteration` measures R²-Gaussian (`r2gs`) iterations",
            a.config.display(),
            config.method().name()
        );
    };
    let g = &mut r.geometry;
    let until = g.densify.as_ref().map_or(0, |d| d.until);
    if a.window < 2 || g.iterations < until + a.window + 1 {
        anyhow::bail!(
            "--window {}: needs 2 ≤ window and densification (until {until}) + window + 1 ≤ \
             iterations ({})",
            a.window,
            g.iterations
        );
    }
    // No evaluation inside the window (the last iteration is scored and left out).
    g.eval_every = 0;
    let (iterations, tv_patch) = (g.iterations, g.loss.tv_patch);
    let scene = Scene::open(&a.scene)?;
    let det = &scene.geometry.detector;
    let vol = &scene.geometry.volume;
    let patch = [vol.nx, vol.ny, vol.nz]
        .iter()
        .map(|&n| tv_patch.min(n) as u64)
        .product::<u64>();
    let pixels = (det.rows * det.cols) as u64;
    let evaluation = a.eval.evaluation()?;
    let bars = Bars::new();
    let (stages, reports) = probed_run(&config, &scene, &evaluation, Some(&bars), true)?;
    bars.finish();
    let trained: Vec<_> = stages.iter().filter(|s| !s.1.is_empty()).collect();
    if trained.len() != reports.len() {
        anyhow::bail!(
            "{} stages reported progress, train.json lists {}",
            trained.len(),
            reports.len()
        );
    }
    let bandwidth = copy_bandwidth();
    let mut rows = Vec::new();
    for ((name, samples), report) in trained.into_iter().zip(&reports) {
        if samples.len() != iterations {
            anyhow::bail!(
                "stage {name}: {} iterations seen of {iterations}",
                samples.len()
            );
        }
        // Intervals between the ends of iterations n−w−1 … n−1 (1-based): the w iterations
        // before the last, which is evaluated.
        let w = &samples[iterations - a.window - 2..iterations - 1];
        let per: Vec<(f64, u64, u64)> = w
            .windows(2)
            .map(|p| {
                (
                    (p[1].0 - p[0].0).as_secs_f64(),
                    p[1].1.bytes - p[0].1.bytes,
                    p[1].1.calls - p[0].1.calls,
                )
            })
            .collect();
        let n = per.len() as f64;
        let time_s = quantile(per.iter().map(|p| p.0 as f32), 0.5) as f64;
        let bytes = per.iter().map(|p| p.1 as f64).sum::<f64>() / n;
        let calls = per.iter().map(|p| p.2 as f64).sum::<f64>() / n;
        let k = report.n_gaussians as u64;
        let must = (4 * PARAMS * k * (1 + 1 + 7) + 12 * pixels + 8 * patch) as f64;
        let bound_s = must / bandwidth;
        eprintln!(
            "{name}: K {k}, {:.2} ms/iteration; allocated {:.1} MB in {calls:.0} calls per \
             iteration = {:.1}× the {:.2} MB it must move; traffic bound {:.3} ms = {:.1} % of \
             the iteration",
            time_s * 1e3,
            bytes / 1e6,
            bytes / must,
            must / 1e6,
            bound_s * 1e3,
            100.0 * bound_s / time_s
        );
        rows.push(json!({
            "stage": name,
            "gaussians": k,
            "iteration_s": time_s,
            "allocated_bytes": bytes,
            "allocations": calls,
            "must_move_bytes": must,
            "allocated_over_must": bytes / must,
            "traffic_bound_s": bound_s,
            "bound_over_iteration": bound_s / time_s,
        }));
    }
    eprintln!(
        "copy bandwidth {:.1} GB/s (read + write, {} threads)",
        bandwidth / 1e9,
        rayon::current_num_threads()
    );
    Ok(json!({
        "config": a.config,
        "scene": a.scene,
        "window": a.window,
        "detector": [det.rows, det.cols],
        "tv_patch_voxels": patch,
        "copy_bandwidth_bytes_per_s": bandwidth,
        "threads": rayon::current_num_threads(),
        "stages": rows,
    }))
}
