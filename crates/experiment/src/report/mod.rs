//! `results.csv`, `report.md` and `figures/` of a suite's output directory, from whatever cells
//! have finished (missing ones are listed, never guessed). Every figure is written as PNG and
//! SVG; `report.md` embeds the PNGs. `report.html` ([`page`]) is the same report to browse, with
//! a slice viewer.

mod page;
mod pictures;
mod sections;
pub mod table;
mod timing;

use crate::execute::{Failure, read_record};
use crate::plan::{Plan, StudyPlan, StudyPoint};
use crate::results::{Row, collect, write_csv};
use crate::suite::{LoadedSuite, StudyKind};
use crate::{Error, Result};
use prism_domain::observe::Observer;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub use page::{HTML, write_html};

pub const REPORT: &str = "report.md";
pub const RESULTS: &str = "results.csv";
pub const FIGURES: &str = "figures";

/// What [`write_report`] wrote.
#[derive(Clone, Debug, Default)]
pub struct Written {
    pub report: PathBuf,
    pub results: PathBuf,
    pub figures: Vec<PathBuf>,
    /// Cells without results.
    pub missing: Vec<String>,
}

/// What the sections draw from.
pub(crate) struct Context<'a> {
    pub loaded: &'a LoadedSuite,
    pub plan: &'a Plan,
    pub out: &'a Path,
    pub rows: &'a [Row],
    pub figures: Vec<PathBuf>,
}

impl<'a> Context<'a> {
    /// `figures/<name>` (without extension) under the output directory.
    pub fn figure_stem(&self, name: &str) -> PathBuf {
        self.out.join(FIGURES).join(name)
    }

    /// Record a saved figure and return the Markdown that embeds its PNG.
    pub fn embed(&mut self, paths: [PathBuf; 2], alt: &str) -> String {
        let rel = paths[0]
            .strip_prefix(self.out)
            .unwrap_or(&paths[0])
            .display()
            .to_string();
        let svg = paths[1]
            .strip_prefix(self.out)
            .unwrap_or(&paths[1])
            .display()
            .to_string();
        self.figures.extend(paths);
        format!("![{alt}]({rel})\n\n*{alt}* ([SVG]({svg}))\n\n")
    }

    /// The palette index of a suite method (stable across figures).
    pub fn colour(&self, method: &str) -> usize {
        self.loaded
            .suite
            .methods
            .keys()
            .position(|k| k == method)
            .unwrap_or(0)
    }

    /// The rows of study `name`.
    pub fn study_rows(&self, name: &str) -> Vec<&'a Row> {
        self.rows.iter().filter(|r| r.study == name).collect()
    }
}

/// Write `results.csv`, the figures and `report.md` under `out` from the finished cells of `plan`;
/// `failures` (of the run that just ended, if any) are listed in the report.
pub fn write_report(
    loaded: &LoadedSuite,
    plan: &Plan,
    out: &Path,
    failures: &[Failure],
    observer: &dyn Observer,
) -> Result<Written> {
    let suite = &loaded.suite;
    let (rows, missing) = collect(suite, plan, out)?;
    let results = out.join(RESULTS);
    write_csv(&results, &rows)?;
    let fig_dir = out.join(FIGURES);
    std::fs::create_dir_all(&fig_dir).map_err(|e| Error::io(&fig_dir, e))?;
    let mut ctx = Context {
        loaded,
        plan,
        out,
        rows: &rows,
        figures: Vec::new(),
    };
    let mut md = header(&ctx);
    for (i, st) in plan.studies.iter().enumerate() {
        observer.phase(&format!("report: study {}", st.spec.name), 0);
        let _ = writeln!(
            md,
            "## Study `{}` ({})\n\n{}\n",
            st.spec.name,
            st.spec.kind.name(),
            st.spec.description.trim()
        );
        if ctx.study_rows(&st.spec.name).is_empty() {
            md.push_str(
                "No cell of this study has finished yet (see *Cells without results*).\n\n",
            );
            continue;
        }
        let section = match st.spec.kind {
            StudyKind::Table | StudyKind::Noise => sections::table(&mut ctx, i),
            StudyKind::Channels => sections::channels(&mut ctx, i),
            StudyKind::Freeze | StudyKind::CurveModel => sections::ablation(&mut ctx, i),
            StudyKind::Holdout => sections::holdout(&mut ctx, i),
        };
        md.push_str(&section?);
    }
    if !missing.is_empty() || !failures.is_empty() {
        md.push_str("## Cells without results\n\n");
        for f in failures {
            let _ = writeln!(md, "- failed: `{}`: {}", f.cell, f.error);
        }
        for m in &missing {
            if !failures.iter().any(|f| f.cell.ends_with(m.as_str())) {
                let _ = writeln!(md, "- not run: `runs/{m}`");
            }
        }
        md.push('\n');
    }
    let report = out.join(REPORT);
    std::fs::write(&report, md).map_err(|e| Error::io(&report, e))?;
    Ok(Written {
        report,
        results,
        figures: ctx.figures,
        missing,
    })
}

/// How the finished run cells were executed, e.g. "two at a time on 1 CPU thread each".
fn executions(ctx: &Context) -> String {
    let mut seen = std::collections::BTreeSet::new();
    let mut unknown = 0;
    for i in 0..ctx.plan.runs.len() {
        let dir = ctx.plan.run_dir(ctx.out, i);
        if !dir.join(prism_recon::record::RunDir::MANIFEST).exists() {
            continue;
        }
        match read_record(&dir).and_then(|r| r.execution) {
            Some(e) => {
                seen.insert(e);
            }
            None => unknown += 1,
        }
    }
    let mut parts: Vec<String> = seen
        .iter()
        .map(|e| {
            let at = match e.concurrent {
                1 => "one at a time".to_string(),
                n => format!("{n} at a time"),
            };
            let each = if e.concurrent > 1 { " each" } else { "" };
            let s = if e.threads == 1 { "" } else { "s" };
            format!("{at} on {} CPU thread{s}{each}", e.threads)
        })
        .collect();
    if unknown > 0 {
        parts.push(format!("{unknown} cells with no record of how"));
    }
    match parts.len() {
        0 => "(no cell has finished)".into(),
        1 => parts.remove(0),
        _ => format!(
            "in several ways: {} (compare times only within one way)",
            parts.join("; ")
        ),
    }
}

/// The report's head: the suite, how it was run, the regime of every scene, the protocol.
fn header(ctx: &Context) -> String {
    let s = &ctx.loaded.suite;
    let mut md = format!(
        "# Experiment suite `{}`\n\n{}\n\n",
        s.name,
        s.description.trim()
    );
    let _ = writeln!(
        md,
        "Written by `prism {}` from `{}`{}. Every cell is an ordinary run directory under `runs/` \
         (its `metrics.json`, `log.jsonl`, `config.resolved.yaml`), every scene a scene directory \
         under `scenes/`; `results.csv` has one row per channel of every run. Times are training \
         seconds (evaluation excluded) of runs made {}{}.\n",
        env!("CARGO_PKG_VERSION"),
        ctx.loaded.file.display(),
        if ctx.loaded.overrides.is_empty() {
            String::new()
        } else {
            format!(
                " with `--set {}`",
                ctx.loaded.overrides.texts().join(" --set ")
            )
        },
        executions(ctx),
        match std::env::var("SLURM_JOB_ID") {
            Ok(id) => format!(" (Slurm job {id})"),
            Err(_) => String::new(),
        }
    );
    md.push_str("**Scenes** (grid, training views, channels; the `undersampled` regime gives round(50·n/256) views to an n³ grid, the paper's angular undersampling at 256³ with 50 views):\n\n");
    md.push_str("| Cell | Scene | Grid | Views | Noise | Seed | Channels |\n|---|---|---|---:|---|---:|---:|\n");
    for c in &ctx.plan.scenes {
        let _ = writeln!(
            md,
            "| `{}` | {} | {} | {} | {} | {} | {} |",
            c.key,
            s.scene_label(&c.scene),
            c.grid_label(),
            c.views,
            c.noise,
            c.seed,
            c.channels
        );
    }
    let e = &s.evaluation;
    let _ = writeln!(
        md,
        "\n**Evaluation** (`docs/metrics.md`): 3-D PSNR and SSIM of each channel's volume normalised by \
         its reference's maximum, on the {} grid; LPIPS {} ({}). Means are over the fitted channels.\n",
        match e.grid {
            Some(n) => format!("resized {n}³"),
            None => "native".to_string(),
        },
        if e.all_slices {
            "over slices along every axis"
        } else {
            "over axial slices"
        },
        match &e.lpips {
            Some(p) => format!("weights {}", p.display()),
            None => "not computed: the suite names no LPIPS weights (`evaluation.lpips`)".into(),
        }
    );
    for (name, sc) in &s.scenes {
        if let Some(r) = sc.roi.as_ref().or(e.roi.as_ref()) {
            let _ = writeln!(
                md,
                "Scene `{name}` is scored inside its {} (`roi`; each run's `metrics.json` \
                 gives the mask's size).\n",
                r.describe()
            );
        }
    }
    if s.scenes
        .values()
        .any(|sc| std::fs::read_to_string(&sc.config).is_ok_and(|t| t.contains("TCIA")))
    {
        md.push_str("*Data used in this work were obtained from The Cancer Imaging Archive (TCIA), collections CPTAC-PDA, CPTAC-LSCC and TCGA-OV.*\n\n");
    }
    md
}

/// A method's label in the suite.
fn label(ctx: &Context, method: &str) -> String {
    ctx.loaded.suite.method_label(method).to_string()
}

/// The cell of study `st` for one scene, method, view count, noise level and seed.
fn point<'a>(
    st: &'a StudyPlan,
    scene: &str,
    method: &str,
    views: usize,
    noise: &str,
    seed: u64,
) -> Option<&'a StudyPoint> {
    st.points.iter().find(|p| {
        p.scene == scene
            && p.method == method
            && p.views == views
            && p.noise == noise
            && p.seed == seed
    })
}

/// The channel-mean row of cell `p` among `rows`.
fn mean_row<'a>(rows: &[&'a Row], p: &StudyPoint) -> Option<&'a Row> {
    rows.iter()
        .find(|r| {
            r.scene == p.scene
                && r.method == p.method
                && r.views == p.views
                && r.noise == p.noise
                && r.seed == p.seed
                && r.variant.is_empty()
                && r.channel == "mean"
        })
        .copied()
}
