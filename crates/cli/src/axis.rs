//! `prism axis <import.yaml>`: estimate a scan's rotation axis without importing it, and
//! optionally write the estimators' curves over a dense range of offsets (`--scan`), the check
//! behind an estimate. See `docs/import.md` ("Rotation axis") and
//! `prism_recon::algorithms::axis`.

use crate::progress::Bars;
use anyhow::Context;
use prism_domain::import::{AxisConfig, AxisMethod, assemble};
use prism_domain::observe::Observer;
use prism_recon::algorithms::axis::{
    AxisMetric, CentralSinogram, Opposing, Sharpness, estimate_axis, resolve,
};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Import config (YAML); image paths are relative to it. Its `axis:` gives the defaults.
    config: PathBuf,
    /// Estimator: auto | opposing | sharpness (default: the config's `axis.method`, else auto).
    #[arg(long, value_name = "METHOD")]
    method: Option<String>,
    /// Search half-width in detector columns around the geometry's offset_u.
    #[arg(long, value_name = "COLUMNS")]
    range: Option<f64>,
    /// Also write every estimator's score at offsets `--step` apart over the range, as CSV.
    #[arg(long, value_name = "FILE.csv")]
    scan: Option<PathBuf>,
    /// Spacing of the `--scan` offsets, columns.
    #[arg(long, default_value_t = 0.25)]
    step: f64,
    #[command(flatten)]
    memory: crate::args::MemoryArgs,
    #[command(flatten)]
    set: crate::args::SetArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Some(crate::import::Read { config, text, .. }) =
        crate::import::read_config(&args.config, &args.set, &args.memory, "reading")?
    else {
        return Ok(());
    };
    let base = args.config.parent().unwrap_or(std::path::Path::new("."));
    let mut axis: AxisConfig = config.axis;
    if let Some(m) = &args.method {
        axis.method = m.parse().map_err(|e| anyhow::anyhow!("--method {e}"))?;
    }
    if axis.method == AxisMethod::Given {
        axis.method = AxisMethod::Auto;
    }
    if let Some(r) = args.range {
        axis.range_px = Some(r);
    }
    if !(args.step.is_finite() && args.step > 0.0) {
        anyhow::bail!("--step must be finite and > 0, got {}", args.step);
    }
    let scene = assemble(&config, base, &text)
        .map_err(|e| e.in_file(&args.config))?
        .scene;
    let d = &scene.geometry.detector;
    let bars = Bars::new();
    let estimate = estimate_axis(&scene, &axis, &bars).map_err(|e| e.in_file(&args.config))?;
    if let Some(path) = &args.scan {
        write_scan(&scene, &axis, args.step, path, &bars)?;
    }
    bars.finish();
    println!("{}: {}", scene.name, estimate.describe());
    let mut estimated = scene.geometry.clone();
    estimated.detector.offset_u = estimate.offset_u;
    println!(
        "the axis projects onto column {:.2} of 0…{} (the detector centre is {:.1})",
        estimated.camera_at(0.0).cx,
        d.cols - 1,
        (d.cols as f64 - 1.0) / 2.0
    );
    if let Some(path) = &args.scan {
        println!("scores at every {} columns → {}", args.step, path.display());
    }
    Ok(())
}

/// Every estimator's score at offsets `step` apart over the search range: `offset_px,
/// offset_u_mm, entropy, negative_fraction, opposing_mse`; the sharpness columns are left empty
/// with `--method opposing` (they reconstruct a slice per offset), the last without a full turn.
fn write_scan(
    scene: &prism_domain::scene::Scene,
    axis: &AxisConfig,
    step: f64,
    path: &std::path::Path,
    bars: &Bars,
) -> anyhow::Result<()> {
    let sino = CentralSinogram::of(scene)?;
    let d = &scene.geometry.detector;
    let centre = d.offset_u / d.pitch_u;
    let range = axis.range_for(d.cols);
    let sharp = match axis.method {
        AxisMethod::Opposing => None,
        _ => Some(Sharpness::new(&sino, centre, range + 2.0, usize::MAX)?),
    };
    let opposing = match resolve(AxisMethod::Auto, &sino) {
        AxisMethod::Opposing => Some(Opposing::new(&sino)?),
        _ => None,
    };
    let n = (range / step).floor() as i64;
    bars.phase("scores over the range", (2 * n + 1) as u64);
    let mut out = String::from("offset_px,offset_u_mm,entropy,negative_fraction,opposing_mse\n");
    for (i, k) in (-n..=n).enumerate() {
        let x = centre + k as f64 * step;
        let sharpness = match &sharp {
            Some(s) => {
                let (entropy, negative) = s.scores(&s.slice(x, None)?);
                format!("{entropy:.6},{negative:.6}")
            }
            None => ",".to_string(),
        };
        let mse = match &opposing {
            Some(o) => format!("{:.9e}", o.score(x, None)?),
            None => String::new(),
        };
        out += &format!("{x:.4},{:.6},{sharpness},{mse}\n", x * d.pitch_u);
        bars.progress(i as u64 + 1, "");
    }
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))
}
