//! `prism bench scaling`: how an iteration's time and a run's peak memory grow with the
//! Gaussian count, the views, the detector, the grid and the channels.
//!
//! From a base point (50 000 Gaussians, 25 views, 128² detector, 128³ grid, 3 channels of the
//! built-in phantom) one axis at a time is swept. At every point each method (R²-Gaussian,
//! 4D-SG's two stages, NAF; NAF has no Gaussian axis) trains for `--warmup` + `--window` + 1
//! iterations with densification off (so the Gaussian count is the point's), without
//! evaluation, in a process of its own; its median iteration time over the window, its peak
//! resident memory (VmHWM) and the memory estimate of `prism recon --dry-run` are recorded.
//! Power laws `t ∝ xᵇ` are fitted per series and axis (least squares in log-log). Writes
//! `scaling.json` and log-log figures `scaling-time.{png,svg}` and `scaling-memory.{png,svg}`;
//! prints the fitted exponents and the estimates off by more than 20 % as JSON on stdout.
//! With `--baseline <previous prism>` every point is also measured by that binary, alternately,
//! and the ratios are reported ([`baseline`]): the guard against a slower or larger iteration.

mod baseline;
mod fit;
mod point;

use fit::{PowerLaw, power_law};
use point::{Measured, Method, Point, measure, simulate_scene};
use prism_experiment::figures::charts::{Lines, Panel, Series};
use prism_experiment::figures::plot::save;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// An estimate further than this fraction from the measured peak is reported.
const ESTIMATE_TOLERANCE: f64 = 0.2;

#[derive(clap::Args)]
pub struct ScalingArgs {
    /// Output directory (scaling.json and the figures).
    #[arg(short, long, default_value = "bench-scaling")]
    output: PathBuf,
    /// Folder holding phantom-4mono.yaml and recon/{r2gs,4dsg,naf}.yaml.
    #[arg(long, default_value = "configs")]
    configs: PathBuf,
    /// Axes to sweep, comma-separated (default: all five).
    #[arg(long, value_delimiter = ',')]
    axes: Vec<Axis>,
    /// Methods to time, comma-separated (default: all three).
    #[arg(long, value_delimiter = ',')]
    methods: Vec<Method>,
    /// Iterations before the timed window (each stage).
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// Timed iterations (each stage); the median is reported.
    #[arg(long, default_value_t = 10)]
    window: usize,
    /// A tiny sweep (24–32³ grid, 24–32² detector, 6–8 views, 500–1 000 Gaussians, 2–3
    /// channels) that checks the bench end to end in seconds.
    #[arg(long)]
    quick: bool,
    /// A previous prism binary: every point is measured by it too, right after this one, and
    /// the ratios this / previous are reported; a series more than 25 % slower (or a peak
    /// 25 % larger) fails the sweep.
    #[arg(long, value_name = "PRISM")]
    baseline: Option<PathBuf>,
    /// One measurement as JSON (internal: the sweep runs each point in its own process).
    #[arg(long, hide = true, requires = "method")]
    point: Option<String>,
    /// The method of `--point`.
    #[arg(long, hide = true)]
    method: Option<Method>,
    /// The scene of `--point`.
    #[arg(long, hide = true, requires = "point")]
    scene: Option<PathBuf>,
}

/// The swept quantities.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum)]
enum Axis {
    Gaussians,
    Views,
    Detector,
    Grid,
    Channels,
}

impl Axis {
    const ALL: [Axis; 5] = [
        Axis::Gaussians,
        Axis::Views,
        Axis::Detector,
        Axis::Grid,
        Axis::Channels,
    ];

    fn name(self) -> &'static str {
        match self {
            Axis::Gaussians => "gaussians",
            Axis::Views => "views",
            Axis::Detector => "detector",
            Axis::Grid => "grid",
            Axis::Channels => "channels",
        }
    }

    fn label(self) -> &'static str {
        match self {
            Axis::Gaussians => "Gaussians",
            Axis::Views => "training views",
            Axis::Detector => "detector pixels per side",
            Axis::Grid => "grid voxels per side",
            Axis::Channels => "channels",
        }
    }

    fn get(self, p: &Point) -> usize {
        match self {
            Axis::Gaussians => p.gaussians,
            Axis::Views => p.views,
            Axis::Detector => p.detector,
            Axis::Grid => p.grid,
            Axis::Channels => p.channels,
        }
    }

    fn set(self, p: Point, v: usize) -> Point {
        let mut q = p;
        match self {
            Axis::Gaussians => q.gaussians = v,
            Axis::Views => q.views = v,
            Axis::Detector => q.detector = v,
            Axis::Grid => q.grid = v,
            Axis::Channels => q.channels = v,
        }
        q
    }

    /// The values swept (the base point's among them).
    fn values(self, quick: bool) -> Vec<usize> {
        match (self, quick) {
            (Axis::Gaussians, false) => vec![10_000, 30_000, 50_000, 100_000, 300_000, 500_000],
            (Axis::Views, false) => vec![13, 25, 50, 100],
            (Axis::Detector, false) => vec![64, 128, 256, 512],
            (Axis::Grid, false) => vec![64, 128, 256],
            (Axis::Channels, false) => vec![2, 3, 4, 8],
            (Axis::Gaussians, true) => vec![500, 1000],
            (Axis::Views, true) => vec![6, 8],
            (Axis::Detector, true) | (Axis::Grid, true) => vec![24, 32],
            (Axis::Channels, true) => vec![2, 3],
        }
    }
}

/// The point every axis is swept from.
fn base(quick: bool) -> Point {
    if quick {
        Point {
            gaussians: 1000,
            views: 8,
            detector: 32,
            grid: 32,
            channels: 2,
        }
    } else {
        Point {
            gaussians: 50_000,
            views: 25,
            detector: 128,
            grid: 128,
            channels: 3,
        }
    }
}

pub fn run(a: ScalingArgs) -> anyhow::Result<()> {
    if let Some(text) = &a.point {
        let p: Point = serde_json::from_str(text)?;
        let method = a.method.expect("clap requires --method with --point");
        let Some(scene) = &a.scene else {
            anyhow::bail!("--point needs --scene");
        };
        let m = measure(&a.configs, scene, p, method, a.warmup, a.window)?;
        println!("{}", serde_json::to_string(&m)?);
        return Ok(());
    }
    let axes = if a.axes.is_empty() {
        Axis::ALL.to_vec()
    } else {
        a.axes.clone()
    };
    let methods = if a.methods.is_empty() {
        vec![Method::R2gs, Method::FourDsg, Method::Naf]
    } else {
        a.methods.clone()
    };
    if let Some(b) = &a.baseline {
        anyhow::ensure!(
            b.is_file(),
            "--baseline {}: not found (the path of a previous prism binary)",
            b.display()
        );
    }
    for file in std::iter::once(a.configs.join(point::SCENE))
        .chain(methods.iter().map(|&m| point::config_file(&a.configs, m)))
    {
        anyhow::ensure!(
            file.is_file(),
            "{}: not found (--configs names the folder of the repository's configs)",
            file.display()
        );
    }
    std::fs::create_dir_all(&a.output)?;
    let base = base(a.quick);
    // Every (point, method) once, in sweep order (the base point is shared by the axes).
    let mut plan: Vec<(Point, Method)> = Vec::new();
    for &axis in &axes {
        for v in axis.values(a.quick) {
            let p = axis.set(base, v);
            for &m in &methods {
                let applies = axis != Axis::Gaussians || m.has_gaussians();
                if applies && !plan.contains(&(p, m)) {
                    plan.push((p, m));
                }
            }
        }
    }
    let exe = std::env::current_exe()?;
    let start = Instant::now();
    // Each scene is simulated once (by this process) and read by every run on it, as
    // `prism recon` reads one.
    let scenes = tempfile::tempdir()?;
    let mut simulated: Vec<Point> = Vec::new();
    let mut results: Vec<(Point, Method, Result<Measured, String>)> = Vec::new();
    // Against `--baseline`: each point's ratios, and how many points the baseline failed.
    let (mut ratios, mut lost) = (Vec::new(), 0);
    for (i, &(p, m)) in plan.iter().enumerate() {
        let key = Point { gaussians: 0, ..p };
        let dir = scenes.path().join(format!(
            "scene-{}v-{}d-{}g-{}c",
            p.views, p.detector, p.grid, p.channels
        ));
        if !simulated.contains(&key) {
            let s = simulate_scene(&a.configs, &p, &dir)?;
            eprintln!(
                "simulated the scene of {} views · {}² · {}³ · {} ch in {s:.1} s",
                p.views, p.detector, p.grid, p.channels
            );
            simulated.push(key);
        }
        let r = measure_apart(&exe, &a, &dir, p, m);
        let elapsed = start.elapsed().as_secs_f64();
        let eta = elapsed / (i + 1) as f64 * (plan.len() - i - 1) as f64;
        eprintln!(
            "[{}/{}] {} at {}: {}  ({elapsed:.0} s, about {eta:.0} s left)",
            i + 1,
            plan.len(),
            m.name(),
            describe(&p),
            match &r {
                Ok(x) => summary(x),
                Err(e) => format!("failed: {e}"),
            }
        );
        if let Some(b) = &a.baseline {
            match (&r, measure_apart(b, &a, &dir, p, m)) {
                (Ok(new), Ok(old)) => {
                    let mut ratio = baseline::ratio(new, &old);
                    eprintln!("    against the baseline: {}", ratio_summary(&ratio));
                    if !baseline::regressions(std::slice::from_ref(&ratio)).is_empty() {
                        // Over the margin: both binaries again, and only what repeats counts.
                        match (
                            measure_apart(&exe, &a, &dir, p, m),
                            measure_apart(b, &a, &dir, p, m),
                        ) {
                            (Ok(new), Ok(old)) => {
                                let again = baseline::ratio(&new, &old);
                                eprintln!("    measured again: {}", ratio_summary(&again));
                                ratio = baseline::confirmed(ratio, &again);
                            }
                            (Err(e), _) | (_, Err(e)) => {
                                eprintln!("    measuring again failed: {e}")
                            }
                        }
                    }
                    ratios.push(ratio);
                }
                (_, Err(e)) => {
                    eprintln!("    the baseline failed: {e}");
                    lost += 1;
                }
                (Err(_), Ok(_)) => {}
            }
        }
        results.push((p, m, r));
    }
    let measured: Vec<&Measured> = results.iter().filter_map(|r| r.2.as_ref().ok()).collect();
    let fits = fit_all(&axes, base, &measured);
    let off: Vec<serde_json::Value> = measured
        .iter()
        .filter_map(|m| {
            let rss = m.peak_rss_bytes? as f64;
            let error = m.estimate_bytes as f64 / rss - 1.0;
            (error.abs() > ESTIMATE_TOLERANCE).then(|| {
                json!({
                    "method": m.method.name(),
                    "point": m.point,
                    "peak_rss_bytes": rss,
                    "estimate_bytes": m.estimate_bytes,
                    "estimate_over_measured": error,
                })
            })
        })
        .collect();
    let regressions = baseline::regressions(&ratios);
    let mut summary = json!({
        "base": base,
        "warmup": a.warmup,
        "window": a.window,
        "threads": rayon::current_num_threads(),
        "wall_s": start.elapsed().as_secs_f64(),
        "fits": fits,
        "estimate_off_by_more_than_20_percent": off,
    });
    if let Some(b) = &a.baseline {
        summary["baseline"] = json!({
            "binary": b,
            "median_ratio": baseline::medians(&ratios),
            "regressions": regressions,
        });
    }
    let failures: Vec<serde_json::Value> = results
        .iter()
        .filter_map(|(p, m, r)| {
            r.as_ref()
                .err()
                .map(|e| json!({"method": m.name(), "point": p, "error": e}))
        })
        .collect();
    let mut full = summary.clone();
    full["measurements"] = serde_json::to_value(&measured)?;
    if a.baseline.is_some() {
        full["baseline"]["ratios"] = serde_json::to_value(&ratios)?;
    }
    full["failed"] = json!(failures);
    let json_path = a.output.join("scaling.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&full)?)?;
    let figures = figures(&a.output, &axes, base, &measured)?;
    eprintln!(
        "wrote {} and {}",
        json_path.display(),
        figures
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!("{}", serde_json::to_string_pretty(&summary)?);
    anyhow::ensure!(
        failures.is_empty(),
        "{} of {} measurements failed (listed in {})",
        failures.len(),
        plan.len(),
        json_path.display()
    );
    anyhow::ensure!(
        lost == 0,
        "the baseline failed {lost} of {} measurements (is it a prism with `bench scaling`?)",
        plan.len()
    );
    anyhow::ensure!(
        regressions.is_empty(),
        "{} regressions against the baseline (more than {:.0} % slower or larger): {}",
        regressions.len(),
        100.0 * baseline::REGRESSION,
        regressions.join("; ")
    );
    Ok(())
}

/// Run one measurement in a child process and read its JSON line.
fn measure_apart(
    exe: &Path,
    a: &ScalingArgs,
    scene: &Path,
    p: Point,
    m: Method,
) -> Result<Measured, String> {
    let out = std::process::Command::new(exe)
        .args(["bench", "scaling", "--point"])
        .arg(serde_json::to_string(&p).map_err(|e| e.to_string())?)
        .args(["--method", m.name()])
        .args(["--warmup", &a.warmup.to_string()])
        .args(["--window", &a.window.to_string()])
        .arg("--configs")
        .arg(&a.configs)
        .arg("--scene")
        .arg(scene)
        .stderr(std::process::Stdio::piped())
        .output()
        .map_err(|e| format!("{}: {e}", exe.display()))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err
            .lines()
            .rev()
            .find(|l| !l.trim().is_empty())
            .unwrap_or("");
        return Err(format!("{} ({})", last.trim(), out.status));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .unwrap_or("");
    serde_json::from_str(line).map_err(|e| format!("its output is not a measurement: {e}"))
}

/// `series ratio×` of every time series of a point's ratios, for the progress lines.
fn ratio_summary(r: &baseline::Ratio) -> String {
    let times: Vec<String> = r.time.iter().map(|(s, v)| format!("{s} {v:.2}×")).collect();
    times.join(", ")
}

fn describe(p: &Point) -> String {
    format!(
        "K {} · {} views · {}² · {}³ · {} ch",
        p.gaussians, p.views, p.detector, p.grid, p.channels
    )
}

fn summary(m: &Measured) -> String {
    let stages: Vec<String> = series_times(m)
        .into_iter()
        .map(|(s, t)| format!("{s} {:.1} ms/it", t * 1e3))
        .collect();
    let mem = match m.peak_rss_bytes {
        Some(r) => format!(
            "peak {:.0} MB, estimate {:.0} MB ({:+.0} %)",
            r as f64 / 1e6,
            m.estimate_bytes as f64 / 1e6,
            100.0 * (m.estimate_bytes as f64 / r as f64 - 1.0)
        ),
        None => "peak unknown".into(),
    };
    format!("{}; {mem}", stages.join(", "))
}

/// The timed series of a measurement: one per method, 4D-SG's two stages apart; a method that
/// trains the channels one after another (R²-Gaussian, NAF) gives the median of its stages.
fn series_times(m: &Measured) -> Vec<(String, f64)> {
    let t: Vec<f64> = m.stages.iter().map(|s| s.iteration_s).collect();
    match m.method {
        Method::FourDsg => t
            .iter()
            .enumerate()
            .map(|(i, &v)| (format!("4dsg stage {}", i + 1), v))
            .collect(),
        _ => {
            let med = prism_domain::metrics::quantile(t.iter().map(|&v| v as f32), 0.5) as f64;
            vec![(m.method.name().to_string(), med)]
        }
    }
}

/// The measurements on `axis` through `base`, as `(x, measurement)` sorted by x.
fn on_axis<'a>(axis: Axis, base: Point, measured: &[&'a Measured]) -> Vec<(f64, &'a Measured)> {
    let mut v: Vec<(f64, &Measured)> = measured
        .iter()
        .filter(|m| axis.set(base, axis.get(&m.point)) == m.point)
        .filter(|m| axis != Axis::Gaussians || m.method.has_gaussians())
        .map(|m| (axis.get(&m.point) as f64, *m))
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}

/// Per axis, the points of each time series and of each method's peak memory and estimate.
fn curves(axis: Axis, base: Point, measured: &[&Measured]) -> BTreeMap<String, Vec<(f64, f64)>> {
    let mut c: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for (x, m) in on_axis(axis, base, measured) {
        for (s, t) in series_times(m) {
            c.entry(format!("time {s}")).or_default().push((x, t));
        }
        if let Some(r) = m.peak_rss_bytes {
            let name = format!("peak {}", m.method.name());
            c.entry(name).or_default().push((x, r as f64));
        }
        let name = format!("estimate {}", m.method.name());
        c.entry(name)
            .or_default()
            .push((x, m.estimate_bytes as f64));
    }
    c
}

#[derive(serde::Serialize)]
struct Fit {
    axis: &'static str,
    /// `time <series>` (seconds per iteration) or `peak <method>` (bytes).
    series: String,
    #[serde(flatten)]
    law: PowerLaw,
    points: Vec<(f64, f64)>,
}

fn fit_all(axes: &[Axis], base: Point, measured: &[&Measured]) -> Vec<Fit> {
    let mut out = Vec::new();
    for &axis in axes {
        for (series, points) in curves(axis, base, measured) {
            if series.starts_with("estimate") {
                continue;
            }
            if let Some(law) = power_law(&points) {
                out.push(Fit {
                    axis: axis.name(),
                    series,
                    law,
                    points,
                });
            }
        }
    }
    out
}

/// Memory in MB (1e6 bytes) on the figures; times as they are.
fn in_units(what: &str, pts: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    let unit = if what == "memory" { 1e6 } else { 1.0 };
    pts.into_iter().map(|(x, y)| (x, y / unit)).collect()
}

/// Colour of a series: one per method (4D-SG's stages in two shades).
fn colour_of(series: &str) -> usize {
    let s = series.split_once(' ').map_or(series, |p| p.1);
    match s {
        "r2gs" => 3,
        "4dsg" | "4dsg stage 2" => 4,
        "4dsg stage 1" => 5,
        "naf" => 2,
        _ => 0,
    }
}

fn figures(
    out: &Path,
    axes: &[Axis],
    base: Point,
    measured: &[&Measured],
) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for (what, stem, y_label) in [
        ("time", "scaling-time", "seconds per iteration"),
        (
            "memory",
            "scaling-memory",
            "MB (peak RSS; dashed: estimate)",
        ),
    ] {
        let panels = axes
            .iter()
            .map(|&axis| {
                let series = curves(axis, base, measured)
                    .into_iter()
                    .filter(|(s, _)| (what == "time") == s.starts_with("time"))
                    .map(|(s, pts)| {
                        let label = s.split_once(' ').map_or(s.as_str(), |p| p.1).to_string();
                        let estimate = s.starts_with("estimate");
                        Series {
                            dashed: estimate,
                            markers: !estimate,
                            label: if estimate {
                                format!("{label} (estimate)")
                            } else {
                                label
                            },
                            ..Series::line("", colour_of(&s), in_units(what, pts))
                        }
                    })
                    .collect();
                Panel {
                    title: format!("against {}", axis.label()),
                    x_label: axis.label().into(),
                    y_label: y_label.into(),
                    log_x: true,
                    log_y: true,
                    series,
                    x_ticks: None,
                }
            })
            .collect();
        let lines = Lines {
            title: format!(
                "prism bench scaling: {what} (base: {})",
                describe(&base).replace('·', ",")
            ),
            panels,
            cols: 3,
            panel: (420, 320),
        };
        written.extend(save(&out.join(stem), &lines)?);
    }
    Ok(written)
}
