//! `prism experiment <suite.yaml> -o <dir>`: every cell of a suite (methods × scenes × view
//! counts × noise × seeds), resumably, then `results.csv`, `report.md` and the figures; or the
//! same as a Slurm job array (`--slurm`); `prism experiment collect` rewrites the report from the
//! finished cells. See `docs/experiments.md` and `prism_experiment`.

use crate::args::{DeviceArg, SetArgs};
use crate::progress::Bars;
use anyhow::{Context, bail};
use prism_domain::observe::{Level, Observer};
use prism_experiment::execute::{
    CellState, ExecOptions, Selection, record_failures, run_plan, run_state, scene_state,
};
use prism_experiment::report::{write_html, write_report};
use prism_experiment::slurm::{SlurmOptions, submit};
use prism_experiment::{LoadedSuite, Plan};
use prism_recon::device::cpu_device;
use prism_recon::evaluate::lpips::Lpips;
use prism_recon::evaluate::{Evaluation, Protocol, SliceAxes};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct Args {
    #[command(subcommand)]
    command: Option<Sub>,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(clap::Subcommand)]
enum Sub {
    /// Write results.csv, report.md and the figures from the cells that have finished (after a
    /// Slurm sweep, or while one runs).
    Collect(CollectArgs),
}

#[derive(clap::Args)]
struct CollectArgs {
    /// The suite file the cells were run with.
    suite: PathBuf,
    /// The suite's output directory.
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    #[command(flatten)]
    set: SetArgs,
    /// Also write report.html: the report to browse, with a slice viewer (its volumes in
    /// report-data/ beside it).
    #[arg(long)]
    html: bool,
}

#[derive(clap::Args)]
struct RunArgs {
    /// Suite file (YAML), e.g. configs/suites/cpu.yaml.
    suite: Option<PathBuf>,
    /// Output directory: scenes/, runs/, results.csv, report.md, figures/.
    #[arg(short = 'o', long = "out")]
    out: Option<PathBuf>,
    #[command(flatten)]
    set: SetArgs,
    /// Also write report.html: the report to browse, with a slice viewer (its volumes in
    /// report-data/ beside it).
    #[arg(long)]
    html: bool,
    /// Compute device of the Gaussian methods (overrides every method config's `device`).
    #[arg(long)]
    device: Option<DeviceArg>,
    /// Redo cells whose scene config, method config or evaluation changed since they ran
    /// (without it such cells are refused).
    #[arg(long)]
    force: bool,
    /// List the cells, their directories, whether they are done and each scene cell's
    /// estimated peak memory; run nothing.
    #[arg(long)]
    dry_run: bool,
    /// Run a cell even when its estimated peak memory exceeds the memory available (every
    /// scene and run cell is checked before it starts).
    #[arg(long)]
    allow_memory: bool,
    /// Run cells at a time, the threads split evenly between them (default: the suite's
    /// `jobs`, else 1). Every cell records how it ran; the report says so.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    jobs: Option<u64>,
    /// Run only the cells whose key contains this text (scenes they need included).
    #[arg(long, value_name = "TEXT")]
    only: Option<String>,
    /// Run only the cells of this study (repeatable; with `--only`, those of its cells whose
    /// key contains the text). The report covers every study, with what has finished.
    #[arg(long, value_name = "NAME")]
    study: Vec<String>,
    /// Run only scene cell I (a Slurm array task).
    #[arg(long, value_name = "I", conflicts_with = "cell")]
    scene_cell: Option<usize>,
    /// Run only run cell I (a Slurm array task); its scene must be simulated.
    #[arg(long, value_name = "I")]
    cell: Option<usize>,
    #[command(flatten)]
    slurm: SlurmArgs,
}

/// `--slurm` and the resources of its tasks.
#[derive(clap::Args)]
struct SlurmArgs {
    /// Write Slurm batch scripts (job arrays: scenes, runs, report) under <out>/slurm and submit
    /// them with sbatch.
    #[arg(long)]
    slurm: bool,
    /// With --slurm: write the scripts but do not submit.
    #[arg(long, requires = "slurm")]
    no_submit: bool,
    #[arg(long, requires = "slurm")]
    partition: Option<String>,
    /// Time limit of each task, e.g. 02:00:00.
    #[arg(long, requires = "slurm")]
    time: Option<String>,
    #[arg(long, requires = "slurm", default_value_t = 2)]
    cpus_per_task: usize,
    /// Memory of each task, e.g. 16G.
    #[arg(long, requires = "slurm")]
    mem: Option<String>,
    /// More #SBATCH arguments (repeatable), e.g. --sbatch-arg=--qos=short.
    #[arg(long = "sbatch-arg", requires = "slurm")]
    sbatch_args: Vec<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Some(Sub::Collect(c)) => collect(c),
        None => run_suite(args.run),
    }
}

fn load(suite: &Path, set: &SetArgs) -> anyhow::Result<(LoadedSuite, Plan)> {
    let loaded = LoadedSuite::load(suite, &set.overrides()?)?;
    let plan = Plan::new(&loaded)?;
    Ok((loaded, plan))
}

/// The suite's evaluation (LPIPS weights loaded on the CPU).
fn evaluation(loaded: &LoadedSuite) -> anyhow::Result<Evaluation> {
    let e = &loaded.suite.evaluation;
    Ok(Evaluation {
        protocol: Protocol {
            grid: e.grid,
            slices: if e.all_slices {
                SliceAxes::All
            } else {
                SliceAxes::Axial
            },
            roi: e.roi.clone(),
        },
        lpips: match &e.lpips {
            Some(p) => Some(std::sync::Arc::new((
                Lpips::load(p, &cpu_device())
                    .with_context(|| format!("{}: evaluation.lpips", loaded.file.display()))?,
                p.clone(),
            ))),
            None => None,
        },
    })
}

fn collect(args: CollectArgs) -> anyhow::Result<()> {
    let (loaded, plan) = load(&args.suite, &args.set)?;
    let bars = Bars::new();
    let w = reports(&loaded, &plan, &args.out, &[], args.html, &bars)?;
    bars.finish();
    summary(&w, plan.runs.len());
    Ok(())
}

/// `report.md` (with results.csv and the figures) and, with `html`, `report.html`.
fn reports(
    loaded: &LoadedSuite,
    plan: &Plan,
    out: &Path,
    failures: &[prism_experiment::execute::Failure],
    html: bool,
    bars: &Bars,
) -> anyhow::Result<prism_experiment::report::Written> {
    let w = write_report(loaded, plan, out, failures, bars)?;
    if html {
        let page = write_html(loaded, plan, out, bars)?;
        bars.note(
            Level::Info,
            &format!(
                "{} ({:.1} MB with {})",
                page.html.display(),
                page.bytes as f64 / 1e6,
                page.data.display()
            ),
        );
    }
    Ok(w)
}

fn summary(w: &prism_experiment::report::Written, cells: usize) {
    eprintln!(
        "{} of {cells} run cells finished → {} ({} figures), {}",
        cells - w.missing.len(),
        w.report.display(),
        w.figures.len() / 2,
        w.results.display()
    );
    const LISTED: usize = 8;
    match w.missing.len() {
        0 => {}
        n if n <= LISTED => eprintln!("not finished: {}", w.missing.join(", ")),
        n => eprintln!(
            "not finished: {}, and {} more (listed in the report)",
            w.missing[..LISTED].join(", "),
            n - LISTED
        ),
    }
}

fn run_suite(a: RunArgs) -> anyhow::Result<()> {
    let (Some(suite), Some(out)) = (&a.suite, &a.out) else {
        bail!("give a suite file and -o <dir> (or `prism experiment collect <suite> -o <dir>`)");
    };
    let (loaded, plan) = load(suite, &a.set)?;
    let bars = Bars::new();
    let evaluation = evaluation(&loaded)?;
    // More cells at a time than cores only adds threads: the count is capped at the cores.
    let wanted = a.jobs.map_or(loaded.suite.jobs as u64, |n| n);
    let cores = rayon::current_num_threads().max(1);
    let jobs = wanted.clamp(1, cores as u64) as usize;
    if wanted > cores as u64 {
        bars.note(
            Level::Warning,
            &format!(
                "jobs {wanted}: this machine has {cores} cores; running {jobs} cells at a time"
            ),
        );
    }
    let options = ExecOptions {
        observer: &bars,
        device: a.device.map(DeviceArg::choice),
        evaluation: &evaluation,
        evaluation_spec: &loaded.suite.evaluation,
        force: a.force,
        jobs,
        allow_memory: a.allow_memory,
    };
    let selection = Selection::of(&plan, a.only.as_deref(), &a.study)?;
    if a.dry_run {
        bars.finish();
        return dry_run(&plan, out, &options, &selection);
    }
    // Only now: a dry run or a refused selection leaves no directory behind.
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    if a.slurm.slurm {
        let mut pass_on = Vec::new();
        for s in &a.set.set {
            pass_on.extend(["--set".to_string(), s.clone()]);
        }
        if let Some(d) = a.device {
            pass_on.extend(["--device".to_string(), d.name().to_string()]);
        }
        if a.force {
            pass_on.push("--force".into());
        }
        if a.allow_memory {
            pass_on.push("--allow-memory".into());
        }
        // The report task writes report.html too (the cell tasks write no report).
        if a.html {
            pass_on.push("--html".into());
        }
        let s = &a.slurm;
        let sub = submit(
            &loaded,
            &plan,
            out,
            &SlurmOptions {
                prism: std::env::current_exe().context("locating the prism binary")?,
                pass_on,
                partition: s.partition.clone(),
                time: s.time.clone(),
                cpus_per_task: s.cpus_per_task,
                mem: s.mem.clone(),
                extra: s.sbatch_args.clone(),
                submit: !s.no_submit,
            },
        )?;
        bars.finish();
        for p in &sub.scripts {
            eprintln!("wrote {}", p.display());
        }
        if !sub.jobs.is_empty() {
            eprintln!(
                "submitted: scenes {} ({} tasks), runs {} ({} tasks), report {} → {}",
                sub.jobs[0],
                plan.scenes.len(),
                sub.jobs[1],
                plan.runs.len(),
                sub.jobs[2],
                out.join("report.md").display()
            );
        }
        return Ok(());
    }
    // One cell (a Slurm task): its error is the command's.
    let single = |r: prism_experiment::Result<bool>, key: &str| -> anyhow::Result<()> {
        let ran = r.map_err(|e| e.in_cell(key))?;
        eprintln!("{key}: {}", if ran { "done" } else { "already finished" });
        Ok(())
    };
    if let Some(i) = a.scene_cell {
        check_index(i, plan.scenes.len(), "--scene-cell")?;
        let r = prism_experiment::execute::make_scene(&plan, out, i, &options);
        return single(r, &format!("scenes/{}", plan.scenes[i].key));
    }
    if let Some(i) = a.cell {
        check_index(i, plan.runs.len(), "--cell")?;
        let r = prism_experiment::execute::run_cell(&plan, out, i, &options);
        return single(r, &format!("runs/{}", plan.runs[i].key));
    }
    let executed = run_plan(&plan, out, &selection, &options);
    record_failures(out, &executed.failures)?;
    let w = reports(&loaded, &plan, out, &executed.failures, a.html, &bars)?;
    bars.finish();
    eprintln!(
        "{} cells run, {} already finished, {} failed",
        executed.ran,
        executed.skipped,
        executed.failures.len()
    );
    summary(&w, plan.runs.len());
    if !executed.failures.is_empty() {
        bars.note(
            Level::Warning,
            "some cells failed (see failures.json and the report)",
        );
        bail!("{} cells failed", executed.failures.len());
    }
    Ok(())
}

fn check_index(i: usize, n: usize, flag: &str) -> anyhow::Result<()> {
    if i >= n {
        bail!("{flag} {i}: the suite has {n} such cells (0..{n})");
    }
    Ok(())
}

fn dry_run(
    plan: &Plan,
    out: &Path,
    options: &ExecOptions,
    selection: &Selection,
) -> anyhow::Result<()> {
    let state = |s: CellState| match s {
        CellState::Done => "done".to_string(),
        CellState::Missing => "to run".to_string(),
        CellState::Rescore => "to score again (the evaluation changed)".to_string(),
        CellState::Changed(why) => format!("changed: {why}"),
    };
    let mark = |selected: bool, s: String| {
        if selected {
            s
        } else {
            format!("{s} (not selected)")
        }
    };
    println!("{} scene cells:", plan.scenes.len());
    for (i, c) in plan.scenes.iter().enumerate() {
        let peak = c.footprint().map_err(|e| e.in_file(&c.config))?;
        println!(
            "  [{i}] scenes/{}  ({}, {} views, {} channels)  {}\n      {} needs ~{}",
            c.key,
            c.grid_label(),
            c.views,
            c.channels,
            mark(selection.has_scene(i), state(scene_state(plan, out, i)?)),
            if c.import { "importing" } else { "simulating" },
            prism_domain::memory::human(peak),
        );
    }
    println!("{} run cells:", plan.runs.len());
    for (i, c) in plan.runs.iter().enumerate() {
        println!(
            "  [{i}] runs/{}  {}",
            c.key,
            mark(
                selection.has_run(i),
                state(run_state(plan, out, i, options)?)
            )
        );
    }
    Ok(())
}
