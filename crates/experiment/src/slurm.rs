//! Sweeps on a Slurm cluster: `prism experiment --slurm` writes three batch scripts under
//! `<out>/slurm/` and submits them: a job array with one task per scene cell, a job array with
//! one task per run cell (after every scene succeeded), and the report (after the runs, whatever
//! their outcome). Each task is `prism experiment <suite> -o <out> --scene-cell i` or
//! `--cell i`: the same binary, suite and overrides, one cell, skipped when already finished.
//! `prism experiment collect` writes the report again at any time.

use crate::plan::Plan;
use crate::suite::LoadedSuite;
use crate::suite::plain_text;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Resources and submission settings.
#[derive(Clone, Debug, PartialEq)]
pub struct SlurmOptions {
    /// The `prism` binary the tasks run (absolute).
    pub prism: PathBuf,
    /// Arguments every task passes on (`--set …`, `--device …`, `--force`).
    pub pass_on: Vec<String>,
    pub partition: Option<String>,
    /// `--time` of each task (e.g. `02:00:00`).
    pub time: Option<String>,
    pub cpus_per_task: usize,
    /// `--mem` of each task (e.g. `8G`).
    pub mem: Option<String>,
    /// More `#SBATCH` arguments, verbatim.
    pub extra: Vec<String>,
    /// Submit (else only write the scripts).
    pub submit: bool,
}

/// What was written and submitted (`slurm/jobs.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Submission {
    pub scripts: Vec<PathBuf>,
    /// Job ids of the scenes array, the runs array and the report (empty when not submitted).
    pub jobs: Vec<String>,
}

impl SlurmOptions {
    /// Refuse a control character (a newline would start a new line of the batch script) in any
    /// option written unquoted into an `#SBATCH` line; errors name the option.
    pub fn validate(&self) -> Result<()> {
        let fields = [
            ("--partition", self.partition.as_deref()),
            ("--time", self.time.as_deref()),
            ("--mem", self.mem.as_deref()),
        ];
        let extra = self
            .extra
            .iter()
            .map(|e| ("--sbatch-arg", Some(e.as_str())));
        for (name, value) in fields.into_iter().chain(extra) {
            if let Some(v) = value {
                plain_text(name, v)?;
            }
        }
        Ok(())
    }
}

/// Single-quote `s` for a POSIX shell.
pub fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

fn script(
    name: &str,
    array: Option<usize>,
    log: &str,
    command: &[String],
    opts: &SlurmOptions,
) -> String {
    let mut s = String::from("#!/bin/bash\n");
    let _ = writeln!(s, "#SBATCH --job-name={name}");
    if let Some(n) = array {
        let _ = writeln!(s, "#SBATCH --array=0-{}", n.saturating_sub(1));
    }
    let _ = writeln!(s, "#SBATCH --output={log}");
    let _ = writeln!(s, "#SBATCH --cpus-per-task={}", opts.cpus_per_task.max(1));
    if let Some(p) = &opts.partition {
        let _ = writeln!(s, "#SBATCH --partition={p}");
    }
    if let Some(t) = &opts.time {
        let _ = writeln!(s, "#SBATCH --time={t}");
    }
    if let Some(m) = &opts.mem {
        let _ = writeln!(s, "#SBATCH --mem={m}");
    }
    for e in &opts.extra {
        let _ = writeln!(s, "#SBATCH {e}");
    }
    s.push_str("set -euo pipefail\n");
    let _ = writeln!(
        s,
        "export RAYON_NUM_THREADS=\"${{SLURM_CPUS_PER_TASK:-{}}}\"",
        opts.cpus_per_task.max(1)
    );
    let cmd: Vec<String> = command
        .iter()
        .map(|a| {
            if a.starts_with('$') {
                format!("\"{a}\"")
            } else {
                shell_quote(a)
            }
        })
        .collect();
    let _ = writeln!(s, "exec {}", cmd.join(" "));
    s
}

/// Write the scripts for `plan` under `<out>/slurm/` and, with `opts.submit`, submit them.
pub fn submit(
    loaded: &LoadedSuite,
    plan: &Plan,
    out: &Path,
    opts: &SlurmOptions,
) -> Result<Submission> {
    opts.validate()?;
    let dir = out.join("slurm");
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs).map_err(|e| Error::io(&logs, e))?;
    let abs = |p: &Path| std::path::absolute(p).map_err(|e| Error::io(p, e));
    let (suite, out_abs, logs) = (abs(&loaded.file)?, abs(out)?, abs(&logs)?);
    let base = |sub: Option<&str>, cell: Option<(&str, &str)>| {
        let mut c = vec![opts.prism.display().to_string(), "experiment".into()];
        if let Some(s) = sub {
            c.push(s.into());
        }
        c.extend([
            suite.display().to_string(),
            "-o".into(),
            out_abs.display().to_string(),
        ]);
        if let Some((flag, var)) = cell {
            c.extend([flag.to_string(), var.to_string()]);
        }
        c.extend(opts.pass_on.iter().cloned());
        c
    };
    let name = &loaded.suite.name;
    plain_text("--out", &logs.display().to_string())?;
    let log = |what: &str| logs.join(what).display().to_string();
    let files = [
        (
            "scenes.sbatch",
            script(
                &format!("prism-{name}-scenes"),
                Some(plan.scenes.len()),
                &log("scene-%a.log"),
                &base(None, Some(("--scene-cell", "$SLURM_ARRAY_TASK_ID"))),
                opts,
            ),
        ),
        (
            "runs.sbatch",
            script(
                &format!("prism-{name}-runs"),
                Some(plan.runs.len()),
                &log("run-%a.log"),
                &base(None, Some(("--cell", "$SLURM_ARRAY_TASK_ID"))),
                opts,
            ),
        ),
        (
            "collect.sbatch",
            script(
                &format!("prism-{name}-report"),
                None,
                &log("collect.log"),
                &base(Some("collect"), None),
                opts,
            ),
        ),
    ];
    let mut scripts = Vec::new();
    for (f, text) in &files {
        let p = dir.join(f);
        std::fs::write(&p, text).map_err(|e| Error::io(&p, e))?;
        scripts.push(p);
    }
    let mut jobs: Vec<String> = Vec::new();
    if opts.submit {
        let deps = [None, Some("afterok"), Some("afterany")];
        for (p, dep) in scripts.iter().zip(deps) {
            let mut cmd = Command::new("sbatch");
            cmd.arg("--parsable");
            if let (Some(kind), Some(prev)) = (dep, jobs.last()) {
                cmd.arg(format!("--dependency={kind}:{prev}"));
            }
            cmd.arg(p);
            let o = cmd.output().map_err(|e| {
                Error::Scheduler(format!(
                    "cannot run `sbatch` ({e}); is Slurm installed? The scripts are in {}",
                    dir.display()
                ))
            })?;
            if !o.status.success() {
                return Err(Error::Scheduler(format!(
                    "sbatch {} failed: {}",
                    p.display(),
                    String::from_utf8_lossy(&o.stderr).trim()
                )));
            }
            let id = String::from_utf8_lossy(&o.stdout)
                .trim()
                .split(';')
                .next()
                .unwrap_or("")
                .to_string();
            if id.is_empty() {
                return Err(Error::Scheduler(format!(
                    "sbatch {} printed no job id",
                    p.display()
                )));
            }
            jobs.push(id);
        }
    }
    let sub = Submission { scripts, jobs };
    let path = dir.join("jobs.json");
    let json =
        serde_json::to_string_pretty(&sub).map_err(|e| Error::field(&path, ".", e.to_string()))?;
    std::fs::write(&path, json + "\n").map_err(|e| Error::io(&path, e))?;
    Ok(sub)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scripts_quote_paths_and_expand_the_task_id() {
        let opts = SlurmOptions {
            prism: "/opt/prism bin/prism".into(),
            pass_on: vec!["--set".into(), "studies.0.seeds=[0, 1]".into()],
            partition: Some("cpu".into()),
            time: Some("01:00:00".into()),
            cpus_per_task: 4,
            mem: None,
            extra: vec!["--qos=short".into()],
            submit: false,
        };
        let cmd = vec![
            "/opt/prism bin/prism".to_string(),
            "it's".into(),
            "--cell".into(),
            "$SLURM_ARRAY_TASK_ID".into(),
        ];
        let s = script("j", Some(3), "/l/%a.log", &cmd, &opts);
        assert!(s.contains("#SBATCH --array=0-2\n") && s.contains("#SBATCH --partition=cpu\n"));
        assert!(s.contains("#SBATCH --qos=short\n") && s.contains("--cpus-per-task=4"));
        assert!(
            s.contains("exec '/opt/prism bin/prism' 'it'\\''s' '--cell' \"$SLURM_ARRAY_TASK_ID\""),
            "{s}"
        );
        assert_eq!(shell_quote("a b"), "'a b'");
    }

    #[test]
    fn a_newline_in_an_option_is_refused_naming_it() {
        let opts = SlurmOptions {
            prism: "/p".into(),
            pass_on: vec![],
            partition: Some("cpu\nrm -rf ~".into()),
            time: None,
            cpus_per_task: 1,
            mem: None,
            extra: vec![],
            submit: false,
        };
        let e = opts.validate().unwrap_err().to_string();
        assert!(
            e.contains("--partition") && e.contains("control character"),
            "{e}"
        );
        let opts = SlurmOptions {
            partition: None,
            extra: vec!["--qos=short\r".into()],
            ..opts
        };
        assert!(
            opts.validate()
                .unwrap_err()
                .to_string()
                .contains("--sbatch-arg")
        );
        assert!(plain_text("x", "a b-c_d").is_ok());
    }
}
