//! Classic-CT benchmark on the built-in spectral phantom, with RTK measured in the same run.
//!
//! Setup (the reference's §2.3 geometry scaled to the paper's system): cone beam, DSO 1000 mm,
//! DSD 1500 mm, `det²` detector over 512 mm, `n³` grid over 256 mm, `views` over a full turn; the
//! object is [`SpectralPhantom::builtin`] (radius 110 mm) at 70 keV: the reference volume is its
//! supersampled material fractions times μ(70 keV), the analytic projections its exact material
//! path lengths times μ. PSNRs divide volumes by the reference's maximum (peak 1).
//!
//! Measured, in one process: Joseph forward projection (time, relative L2 error vs the analytic
//! projections), its exact adjoint (time, dot-product test), the voxel-driven FDK backprojector,
//! FDK at `views` and at `full_views`, SART and CGLS (time, PSNR), optionally the forward-projection
//! error at 256³, and the SART > CGLS > FDK ordering on the `phantom-3mono` configuration
//! (64³, 96², 50 views, 40/70/100 keV, default iterations). Then `bench/rtk_classic.py` runs RTK's
//! Joseph projector and FDK on the same volume and projections (skipped with a message when RTK is
//! not importable). Timings on both sides are the median of `repeats` runs, reported with the
//! minimum and maximum (`*_min_s`, `*_max_s`): one run on a shared machine varies by tens of
//! percent.

use super::{ClassicConfig, ClassicMethod, reconstruct_channel};
use crate::algorithms::{SartOptions, Window, cgls, fdk, sart};
use crate::{Error, Result};
use ndarray::Array3;
use prism_domain::geometry::{Beam, Detector, Geometry, VolumeGrid};
use prism_domain::metrics::psnr;
use prism_domain::observe::{Level, Observer};
use prism_domain::phantom::SpectralPhantom;
use prism_domain::physics::ChannelSpec;
use prism_domain::projector::{Joseph, backproject_voxel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Benchmark parameters; [`Default`] is the acceptance setup (128³, 256², 50 views).
#[derive(Clone, Debug)]
pub struct BenchOptions {
    pub n: usize,
    pub det: usize,
    pub views: usize,
    /// Views of the dense FDK run (0 skips it).
    pub full_views: usize,
    pub sart_epochs: usize,
    pub cgls_iterations: usize,
    /// Also measure the forward-projection error at 256³ (256² detector).
    pub fp_256: bool,
    /// Run the SART > CGLS > FDK ordering check on phantom-3mono.
    pub ordering: bool,
    /// Python interpreter for the RTK script (`None` skips RTK).
    pub python: Option<String>,
    /// RTK threads.
    pub rtk_threads: usize,
    /// Timed runs per operation (the median is reported, with min and max).
    pub repeats: usize,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            n: 128,
            det: 256,
            views: 50,
            full_views: 360,
            sart_epochs: 3,
            cgls_iterations: 10,
            fp_256: true,
            ordering: true,
            python: Some(std::env::var("PRISM_PYTHON").unwrap_or_else(|_| "python3".into())),
            rtk_threads: 2,
            repeats: 5,
        }
    }
}

/// The benchmark geometry: `n³` over 256 mm, `det²` over 512 mm, `views` over a full turn.
pub fn bench_geometry(n: usize, det: usize, views: usize) -> Geometry {
    Geometry {
        beam: Beam::Cone,
        dso: 1000.0,
        dsd: 1500.0,
        detector: Detector {
            rows: det,
            cols: det,
            pitch_u: 512.0 / det as f64,
            pitch_v: 512.0 / det as f64,
            offset_u: 0.0,
            offset_v: 0.0,
        },
        volume: VolumeGrid::cube(n, 256.0 / n as f64),
        angles_rad: Geometry::full_turn(views),
        vectors: None,
    }
}

/// Reference volume (μ, mm⁻¹) and analytic projections of the built-in phantom in `channel`.
pub fn phantom_data(
    geometry: &Geometry,
    channel: &ChannelSpec,
) -> Result<(Array3<f32>, Array3<f32>)> {
    let ph = SpectralPhantom::builtin(110.0)?;
    let fractions = ph.fractions(&geometry.volume, 3)?;
    let paths = ph.material_paths(geometry)?;
    Ok((channel.volume(&fractions)?, channel.project(&paths)?))
}

/// Wall-clock statistics of repeated runs, seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Timing {
    median: f64,
    min: f64,
    max: f64,
}

impl Timing {
    /// Median (mean of the middle two for an even count), min and max of `samples` (non-empty).
    fn of(samples: &[f64]) -> Timing {
        let mut s = samples.to_vec();
        s.sort_by(f64::total_cmp);
        let n = s.len();
        let median = if n % 2 == 1 {
            s[n / 2]
        } else {
            0.5 * (s[n / 2 - 1] + s[n / 2])
        };
        Timing {
            median,
            min: s[0],
            max: s[n - 1],
        }
    }

    /// Insert the median as `key` and the extremes as `<stem>_min_s`, `<stem>_max_s`, where
    /// `stem` is `key` without its `_s` suffix.
    fn insert(&self, out: &mut Value, key: &str) {
        let stem = key.strip_suffix("_s").unwrap_or(key);
        out[key] = json!(self.median);
        out[format!("{stem}_min_s")] = json!(self.min);
        out[format!("{stem}_max_s")] = json!(self.max);
    }
}

/// Run `f` `repeats` times (at least once); the last result and the timing statistics.
fn timed<T, E: Into<Error>>(
    repeats: usize,
    mut f: impl FnMut() -> std::result::Result<T, E>,
) -> Result<(T, Timing)> {
    let mut times = Vec::with_capacity(repeats.max(1));
    let mut out = None;
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        let r = f().map_err(Into::into)?;
        times.push(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    Ok((out.expect("at least one run"), Timing::of(&times)))
}

fn rel_l2(a: &Array3<f32>, b: &Array3<f32>) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

/// PSNR after dividing both volumes by the reference's maximum.
fn norm_psnr(pred: &Array3<f32>, truth: &Array3<f32>) -> Result<f64> {
    let peak = truth.fold(0.0f32, |a, &b| a.max(b));
    if peak <= 0.0 {
        return Err(Error::invalid("reference", "has no positive value"));
    }
    Ok(psnr(
        pred.mapv(|x| x / peak).view(),
        truth.mapv(|x| x / peak).view(),
        1.0,
    )?)
}

/// Run the benchmark; returns the JSON object (also suitable for printing).
pub fn run(opts: &BenchOptions, observer: &dyn Observer) -> Result<Value> {
    let log = |msg: &str| observer.phase(msg, 0);
    let mono70 = ChannelSpec::Mono { kev: 70.0 };
    let g = bench_geometry(opts.n, opts.det, opts.views);
    log(&format!(
        "{}³ volume, {}² detector, {} views: voxelising the phantom",
        opts.n, opts.det, opts.views
    ));
    let (truth, analytic) = phantom_data(&g, &mono70)?;
    let a = Joseph::new(&g)?;
    let r = opts.repeats;

    log("Joseph forward projection");
    let (fp, fp_t) = timed(r, || a.forward(truth.view()))?;
    let fp_err = rel_l2(&fp, &analytic);
    log("exact adjoint");
    let (_, bp_t) = timed(r, || a.adjoint(analytic.view()))?;
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let x = Array3::from_shape_simple_fn(g.volume.shape_zyx(), || rng.random_range(-1.0f32..1.0));
    let y = Array3::from_shape_simple_fn(a.projection_shape(g.views()), || {
        rng.random_range(-1.0f32..1.0)
    });
    let lhs = prism_domain::projector::dot(a.forward(x.view())?.view(), y.view());
    let rhs = prism_domain::projector::dot(x.view(), a.adjoint(y.view())?.view());
    let adjoint_rel_err = (lhs - rhs).abs() / lhs.abs();
    log("voxel-driven FDK backprojection");
    let views: Vec<usize> = (0..g.views()).collect();
    let ones = vec![1.0; g.views()];
    let (_, voxel_bp_t) = timed(r, || backproject_voxel(&g, analytic.view(), &views, &ones))?;
    log("FDK");
    let (rec, fdk_t) = timed(r, || fdk(&g, analytic.view(), Window::RamLak))?;
    let fdk_psnr = norm_psnr(&rec, &truth)?;

    let mut out = json!({
        "setup": {
            "volume": opts.n, "detector": opts.det, "views": opts.views,
            "dso_mm": g.dso, "dsd_mm": g.dsd, "voxel_mm": g.volume.dx, "pitch_mm": g.detector.pitch_u,
            "object": "SpectralPhantom::builtin(110 mm) at 70 keV",
            "threads": rayon::current_num_threads(), "timing": format!("median of {} (min, max in *_min_s, *_max_s)", r.max(1)),
        },
        "adjoint_rel_err": adjoint_rel_err,
        "fp_rel_err_vs_analytic": fp_err,
        "fp_mrays_per_s": (g.views() * g.detector.rows * g.detector.cols) as f64 / fp_t.median / 1e6,
        "voxel_bp_gups": (g.volume.len() * g.views()) as f64 / voxel_bp_t.median / 1e9,
        "fdk_psnr": fdk_psnr,
    });
    fp_t.insert(&mut out, "fp_s");
    bp_t.insert(&mut out, "bp_s");
    voxel_bp_t.insert(&mut out, "voxel_bp_s");
    fdk_t.insert(&mut out, "fdk_s");

    if opts.full_views > 0 {
        log(&format!("FDK at {} views", opts.full_views));
        let gf = bench_geometry(opts.n, opts.det, opts.full_views);
        let (_, proj) = phantom_data(&gf, &mono70)?;
        let rec = fdk(&gf, proj.view(), Window::RamLak)?;
        out["fdk_full_views"] = json!(opts.full_views);
        out["fdk_full_psnr"] = json!(norm_psnr(&rec, &truth)?);
    }
    if opts.sart_epochs > 0 {
        log(&format!("SART, {} epochs", opts.sart_epochs));
        let so = SartOptions {
            iterations: opts.sart_epochs,
            ..SartOptions::default()
        };
        let t = Instant::now();
        let rec = sart(&a, analytic.view(), None, &so, &mut |_| {})?;
        out["sart_epochs"] = json!(opts.sart_epochs);
        out["sart_s"] = json!(t.elapsed().as_secs_f64());
        out["sart_psnr"] = json!(norm_psnr(&rec, &truth)?);
    }
    if opts.cgls_iterations > 0 {
        log(&format!("CGLS, {} iterations", opts.cgls_iterations));
        let t = Instant::now();
        let rec = cgls(&a, analytic.view(), None, opts.cgls_iterations, &mut |_| {})?;
        out["cgls_iterations"] = json!(opts.cgls_iterations);
        out["cgls_s"] = json!(t.elapsed().as_secs_f64());
        out["cgls_psnr"] = json!(norm_psnr(&rec, &truth)?);
    }
    if opts.fp_256 {
        log("forward-projection error at 256³ / 256²");
        let g2 = bench_geometry(256, 256, opts.views);
        let (t2, p2) = phantom_data(&g2, &mono70)?;
        let fp2 = Joseph::new(&g2)?.forward(t2.view())?;
        out["fp_rel_err_vs_analytic_256"] = json!(rel_l2(&fp2, &p2));
    }
    if opts.ordering {
        out["ordering"] = ordering(observer)?;
    }
    let rtk = match &opts.python {
        Some(py) => run_rtk(
            observer,
            py,
            opts.rtk_threads,
            r.max(1),
            &g,
            &truth,
            &analytic,
        )?,
        None => json!({"available": false, "reason": "RTK comparison disabled"}),
    };
    if rtk["available"] == json!(true) {
        let ratio = |k: &str| {
            rtk[k]
                .as_f64()
                .map(|v| v / out[k].as_f64().unwrap_or(f64::NAN))
        };
        // Worst and best case over the repeats: RTK's fastest over our slowest, and vice versa.
        let range = |k: &str| {
            let f = |side: &Value, key: String| side[key].as_f64().unwrap_or(f64::NAN);
            [
                f(&rtk, format!("{k}_min_s")) / f(&out, format!("{k}_max_s")),
                f(&rtk, format!("{k}_max_s")) / f(&out, format!("{k}_min_s")),
            ]
        };
        out["ratios"] = json!({
            "fp_speedup_vs_rtk": ratio("fp_s"),
            "fp_speedup_range": range("fp"),
            "fdk_speedup_vs_rtk": ratio("fdk_s"),
            "fdk_speedup_range": range("fdk"),
            "fp_err_ours_over_rtk": fp_err / rtk["fp_rel_err_vs_analytic"].as_f64().unwrap_or(f64::NAN),
            "fdk_psnr_ours_minus_rtk": fdk_psnr - rtk["fdk_psnr"].as_f64().unwrap_or(f64::NAN),
        });
    } else if let Some(reason) = rtk["reason"].as_str() {
        observer.note(Level::Warning, &format!("RTK skipped: {reason}"));
    }
    out["rtk"] = rtk;
    Ok(out)
}

/// Mean PSNR over 40/70/100 keV of FDK, SART and CGLS (recon defaults) on phantom-3mono.
pub fn ordering(observer: &dyn Observer) -> Result<Value> {
    let log = |msg: &str| observer.phase(msg, 0);
    log("ordering on phantom-3mono (64³, 96², 50 views, 40/70/100 keV)");
    let mut g = bench_geometry(64, 96, 50);
    g.detector.pitch_u = 512.0 / 96.0;
    g.detector.pitch_v = 512.0 / 96.0;
    let views: Vec<usize> = (0..g.views()).collect();
    let mut means = serde_json::Map::new();
    let data: Vec<_> = [40.0, 70.0, 100.0]
        .iter()
        .map(|&kev| phantom_data(&g, &ChannelSpec::Mono { kev }))
        .collect::<Result<_>>()?;
    for method in [ClassicMethod::Fdk, ClassicMethod::Sart, ClassicMethod::Cgls] {
        let cfg = ClassicConfig::new(method);
        let t = Instant::now();
        let mut sum = 0.0;
        for (truth, proj) in &data {
            let rec = reconstruct_channel(&cfg, &g, proj.view(), &views, &mut |_| {})?;
            sum += norm_psnr(&rec, truth)?;
        }
        means.insert(
            method.name().into(),
            json!({"mean_psnr": sum / data.len() as f64, "iterations": cfg.resolved_iterations(), "s": t.elapsed().as_secs_f64()}),
        );
    }
    let p = |m: &str| means[m]["mean_psnr"].as_f64().unwrap_or(f64::NAN);
    let holds = p("sart") > p("cgls") && p("cgls") > p("fdk");
    means.insert("sart_gt_cgls_gt_fdk".into(), json!(holds));
    Ok(Value::Object(means))
}

/// Path of the RTK script in a source checkout.
pub fn rtk_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../bench/rtk_classic.py")
}

fn run_rtk(
    observer: &dyn Observer,
    python: &str,
    threads: usize,
    repeats: usize,
    g: &Geometry,
    truth: &Array3<f32>,
    analytic: &Array3<f32>,
) -> Result<Value> {
    let script = rtk_script();
    if !script.exists() {
        return Ok(
            json!({"available": false, "reason": format!("{} not found", script.display())}),
        );
    }
    let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let w = |name: &str, a: &Array3<f32>| -> Result<()> {
        let p = dir.path().join(name);
        ndarray_npy::write_npy(&p, a).map_err(|e| Error::field(&p, "data", e.to_string()))
    };
    w("volume.npy", truth)?;
    w("analytic.npy", analytic)?;
    let gp = dir.path().join("geometry.json");
    std::fs::write(
        &gp,
        serde_json::to_string(g).map_err(|e| Error::field(&gp, ".", e.to_string()))?,
    )
    .map_err(|e| Error::io(&gp, e))?;
    observer.phase(&format!("RTK via {python} {}", script.display()), 0);
    let output = match std::process::Command::new(python)
        .arg(&script)
        .arg(dir.path())
        .arg(threads.to_string())
        .arg(repeats.to_string())
        .output()
    {
        Ok(o) => o,
        Err(e) => {
            return Ok(json!({"available": false, "reason": format!("cannot run {python}: {e}")}));
        }
    };
    let stdout = String::from_utf8_lossy(&output.stdout);
    match serde_json::from_str::<Value>(stdout.trim()) {
        Ok(v) if output.status.success() => Ok(v),
        _ => Ok(json!({
            "available": false,
            "reason": format!("RTK script failed ({}): {}", output.status, String::from_utf8_lossy(&output.stderr).trim()),
        })),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timing_reports_median_min_and_max() {
        let t = Timing::of(&[0.3, 0.1, 0.5, 0.2, 0.4]);
        assert_eq!(
            t,
            Timing {
                median: 0.3,
                min: 0.1,
                max: 0.5
            }
        );
        let t = Timing::of(&[4.0, 1.0, 2.0, 3.0]);
        assert_eq!(t.median, 2.5);
        let mut v = json!({});
        t.insert(&mut v, "fp_s");
        assert_eq!(v, json!({"fp_s": 2.5, "fp_min_s": 1.0, "fp_max_s": 4.0}));
    }
}
