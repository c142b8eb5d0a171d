//! One measurement of `prism bench scaling`, run in its own process (so its peak resident memory
//! is its own): open the point's simulated scene, train one method for a short window with a
//! fixed Gaussian count (scored at the end, as any run), and report the median iteration time of every stage, the peak RSS and
//! the memory estimate.

use super::super::probe::probed_run;
use prism_domain::metrics::quantile;
use prism_domain::observe::Silent;
use prism_domain::scene::Scene;
use prism_domain::simulate::{SimulateConfig, simulate};
use prism_domain::yaml::Overrides;
use prism_recon::MethodConfig;
use prism_recon::evaluate::Evaluation;
use prism_recon::pipeline::run_footprint;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// Where on the sweep a measurement is: the scene's size and the Gaussian count.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Point {
    /// Gaussians at the start (densification off, so also throughout).
    pub gaussians: usize,
    /// Training views, evenly over 360°.
    pub views: usize,
    /// Detector pixels per side.
    pub detector: usize,
    /// Volume voxels per side.
    pub grid: usize,
    /// Monoenergetic channels, evenly from 40 to 100 keV.
    pub channels: usize,
}

/// The methods the sweep times.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    R2gs,
    #[value(name = "4dsg")]
    #[serde(rename = "4dsg")]
    FourDsg,
    Naf,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::R2gs => "r2gs",
            Method::FourDsg => "4dsg",
            Method::Naf => "naf",
        }
    }

    /// Whether the Gaussian count is one of its sizes (NAF has no Gaussians).
    pub fn has_gaussians(self) -> bool {
        self != Method::Naf
    }

    fn overrides(self, p: &Point, iterations: usize) -> Vec<String> {
        // No scoring during training (NAF's schedule needs a positive period: the last
        // iteration, which the window leaves out).
        let every = if self == Method::Naf { iterations } else { 0 };
        let mut o = vec![
            format!("iterations={iterations}"),
            format!("eval_every={every}"),
        ];
        if self.has_gaussians() {
            o.push("densify=".into());
            o.push(format!("init.n_points={}", p.gaussians));
        }
        if self == Method::FourDsg {
            o.push(format!("stage2.iterations={iterations}"));
        }
        o
    }
}

/// One stage's cost.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StageCost {
    /// The stage as the run names it (`geometry`, `gscnet`, a channel for per-channel methods).
    pub stage: String,
    /// Gaussians during the window (absent for NAF).
    pub gaussians: Option<usize>,
    /// Median seconds per iteration over the window.
    pub iteration_s: f64,
}

/// What one measurement gives.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Measured {
    pub point: Point,
    pub method: Method,
    pub stages: Vec<StageCost>,
    /// Peak resident memory of the process (VmHWM), bytes; absent where the system does not say.
    pub peak_rss_bytes: Option<u64>,
    /// The estimate `prism recon --dry-run` gives for the same run, bytes.
    pub estimate_bytes: u64,
    /// Seconds of the whole run (set-up, training, output, scoring).
    pub run_s: f64,
}

/// The scene config every point is simulated from.
pub const SCENE: &str = "phantom-4mono.yaml";

/// Overrides of [`SCENE`] that give `p`'s scene (no test views, `c` channels).
pub fn scene_overrides(p: &Point) -> Vec<String> {
    let kev: Vec<String> = (0..p.channels)
        .map(|i| {
            let e = if p.channels < 2 {
                70.0
            } else {
                40.0 + 60.0 * i as f64 / (p.channels - 1) as f64
            };
            format!("{{kind: mono, kev: {e:.1}}}")
        })
        .collect();
    vec![
        format!("geometry.volume.n={}", p.grid),
        format!("geometry.detector.rows={}", p.detector),
        format!("geometry.detector.cols={}", p.detector),
        format!("geometry.views={}", p.views),
        "geometry.test_views=0".into(),
        format!("channels=[{}]", kev.join(", ")),
    ]
}

/// The method's config file under `configs`.
pub fn config_file(configs: &Path, method: Method) -> std::path::PathBuf {
    configs
        .join("recon")
        .join(format!("{}.yaml", method.name()))
}

/// Simulate `p`'s scene (the Gaussian count aside) into `dir`; returns the seconds it took.
pub fn simulate_scene(configs: &Path, p: &Point, dir: &Path) -> anyhow::Result<f64> {
    let scene_file = configs.join(SCENE);
    let overrides = Overrides::parse(scene_overrides(p))?;
    let cfg = SimulateConfig::load_with(&scene_file, &overrides)?;
    let t = Instant::now();
    simulate(&cfg, Some(&scene_file), &Silent)?.save(dir)?;
    Ok(t.elapsed().as_secs_f64())
}

/// Measure `method` at `p` on its scene (in `scene`, from [`simulate_scene`]): `warmup`
/// iterations, then `window` timed ones, then one more (a stage's last iteration is followed by
/// its final bookkeeping, so it is left out). The run is scored at the end, as a user's is, so
/// its peak memory is the one the estimate describes.
pub fn measure(
    configs: &Path,
    scene: &Path,
    p: Point,
    method: Method,
    warmup: usize,
    window: usize,
) -> anyhow::Result<Measured> {
    anyhow::ensure!(
        warmup >= 1 && window >= 1,
        "--warmup and --window must be ≥ 1"
    );
    let scene = Scene::open(scene)?;
    let iterations = warmup + window + 1;
    let file = config_file(configs, method);
    let config =
        MethodConfig::load_with(&file, &Overrides::parse(method.overrides(&p, iterations))?)?;
    let evaluation = Evaluation::default();
    let estimate_bytes = run_footprint(&config, &scene, &evaluation).total();
    let t = Instant::now();
    let (stages, reports) = probed_run(&config, &scene, &evaluation, None, method.has_gaussians())?;
    let run_s = t.elapsed().as_secs_f64();
    let trained: Vec<_> = stages
        .into_iter()
        .filter(|s| s.1.len() == iterations)
        .collect();
    anyhow::ensure!(
        !trained.is_empty(),
        "{}: no stage reported {iterations} iterations",
        method.name()
    );
    if method.has_gaussians() {
        anyhow::ensure!(
            trained.len() == reports.len(),
            "{} stages reported progress, train.json lists {}",
            trained.len(),
            reports.len()
        );
    }
    let stages = trained
        .iter()
        .enumerate()
        .map(|(i, (name, samples))| {
            // Intervals ending at iterations warmup + 1 … warmup + window (1-based).
            let w = &samples[warmup - 1..warmup + window];
            let times = w.windows(2).map(|q| (q[1].0 - q[0].0).as_secs_f32());
            StageCost {
                stage: name.clone(),
                gaussians: reports.get(i).map(|r| r.n_gaussians),
                iteration_s: quantile(times, 0.5) as f64,
            }
        })
        .collect();
    Ok(Measured {
        point: p,
        method,
        stages,
        peak_rss_bytes: peak_rss(),
        estimate_bytes,
        run_s,
    })
}

/// This process's peak resident set (VmHWM in /proc/self/status), bytes.
fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
