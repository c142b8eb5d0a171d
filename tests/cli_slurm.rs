//! `prism experiment --slurm` against a real single-node Slurm (Debian's `slurm-wlm` and
//! `munge`, installed by `.ci/run`), started by this test in a temporary directory with its own
//! munge key, ports and state: a 4-cell suite is submitted as job arrays, runs, and is collected.
//! Where Slurm cannot start here (not installed, not root), the test says so and passes without
//! checking anything.

mod common;

use common::{path, phantom_config, prism};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// The daemons of a private cluster; stopped on drop.
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
}

impl Drop for Cluster {
    fn drop(&mut self) {
        for pid in ["slurmd.pid", "slurmctld.pid", "munged.pid"] {
            if let Ok(p) = std::fs::read_to_string(self.dir.join(pid)) {
                let _ = Command::new("kill").arg(p.trim()).status();
            }
        }
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .unwrap_or(0)
}

fn output(cmd: &str, args: &[&str]) -> Option<String> {
    let o = Command::new(cmd).args(args).output().ok()?;
    o.status
        .success()
        .then(|| String::from_utf8_lossy(&o.stdout).trim().to_string())
}

/// Start munged, slurmctld and slurmd in `dir`, or say why not.
fn start(dir: &Path) -> Result<Cluster, String> {
    for bin in ["munged", "slurmctld", "slurmd", "sbatch", "squeue", "sinfo"] {
        if output("sh", &["-c", &format!("command -v {bin}")]).is_none() {
            return Err(format!(
                "`{bin}` is not installed (apt-get install slurm-wlm munge)"
            ));
        }
    }
    if output("id", &["-u"]).as_deref() != Some("0") {
        return Err("slurmd must run as root".into());
    }
    let host = output("hostname", &["-s"]).ok_or("no hostname")?;
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let d = dir.display();
    let m = dir.join("munge");
    std::fs::create_dir_all(&m).map_err(|e| e.to_string())?;
    std::fs::create_dir_all(dir.join("state")).map_err(|e| e.to_string())?;
    std::fs::create_dir_all(dir.join("spool")).map_err(|e| e.to_string())?;
    let key: Vec<u8> = (0..1024u32)
        .map(|i| (i.wrapping_mul(2654435761) >> 13) as u8)
        .collect();
    std::fs::write(m.join("munge.key"), key).map_err(|e| e.to_string())?;
    Command::new("chmod")
        .args(["600", path(&m.join("munge.key"))])
        .status()
        .map_err(|e| e.to_string())?;
    let cluster = Cluster {
        dir: dir.to_path_buf(),
        conf: dir.join("slurm.conf"),
    };
    let ok = Command::new("munged")
        .args([
            "--force",
            &format!("--key-file={d}/munge/munge.key"),
            &format!("--socket={d}/munge/munge.sock"),
            &format!("--pid-file={d}/munged.pid"),
            &format!("--log-file={d}/munge/munged.log"),
            &format!("--seed-file={d}/munge/munged.seed"),
        ])
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        return Err("munged did not start".into());
    }
    let conf = format!(
        "ClusterName=prismtest\nSlurmctldHost={host}\nSlurmUser=root\nAuthType=auth/munge\n\
         AuthInfo=socket={d}/munge/munge.sock\nCredType=cred/munge\nSlurmctldPort={}\n\
         SlurmdPort={}\nStateSaveLocation={d}/state\nSlurmdSpoolDir={d}/spool\n\
         SlurmctldPidFile={d}/slurmctld.pid\nSlurmdPidFile={d}/slurmd.pid\n\
         SlurmctldLogFile={d}/slurmctld.log\nSlurmdLogFile={d}/slurmd.log\n\
         ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nMpiDefault=none\n\
         SchedulerType=sched/backfill\nSelectType=select/cons_tres\nSelectTypeParameters=CR_Core\n\
         ReturnToService=2\nJobCompType=jobcomp/none\nAccountingStorageType=accounting_storage/none\n\
         JobAcctGatherType=jobacct_gather/none\nNodeName={host} CPUs={cpus} State=UNKNOWN\n\
         PartitionName=test Nodes={host} Default=YES MaxTime=INFINITE State=UP\n",
        free_port(),
        free_port()
    );
    std::fs::write(&cluster.conf, conf).map_err(|e| e.to_string())?;
    for daemon in ["slurmctld", "slurmd"] {
        let ok = Command::new(daemon)
            .args(["-f", path(&cluster.conf)])
            .env("SLURM_CONF", &cluster.conf)
            .status()
            .is_ok_and(|s| s.success());
        if !ok {
            return Err(format!("{daemon} did not start (see {d}/{daemon}.log)"));
        }
    }
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(30) {
        let state = Command::new("sinfo")
            .args(["-h", "-o", "%T"])
            .env("SLURM_CONF", &cluster.conf)
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .unwrap_or_default();
        if state == "idle" {
            return Ok(cluster);
        }
        std::thread::sleep(Duration::from_millis(300));
    }
    Err(format!(
        "the node did not become idle in 30 s (see {d}/slurmctld.log)"
    ))
}

#[test]
fn a_four_cell_suite_is_submitted_as_job_arrays_and_collected() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = match start(&dir.path().join("slurm")) {
        Ok(c) => c,
        Err(why) => {
            eprintln!("SKIPPED: no single-node Slurm could start here: {why}");
            return;
        }
    };
    let d = dir.path();
    std::fs::write(
        d.join("p.yaml"),
        phantom_config("p", 30, 16, 24, &[40, 100]),
    )
    .unwrap();
    std::fs::write(d.join("fdk.yaml"), "method: fdk\n").unwrap();
    std::fs::write(d.join("sart.yaml"), "method: sart\niterations: 1\n").unwrap();
    std::fs::write(d.join("cgls.yaml"), "method: cgls\niterations: 2\n").unwrap();
    std::fs::write(
        d.join("r2gs.yaml"),
        "method: r2gs\niterations: 8\ninit: { n_points: 300 }\ndensify: { from: 2, until: 4, every: 2 }\n",
    )
    .unwrap();
    let suite = d.join("suite.yaml");
    std::fs::write(
        &suite,
        "name: four\nscenes:\n  p: { config: p.yaml }\nmethods:\n  fdk: { config: fdk.yaml }\n  \
         sart: { config: sart.yaml }\n  cgls: { config: cgls.yaml }\n  r2gs: { config: r2gs.yaml }\n\
         studies:\n  - { name: t, kind: table, scenes: [p], methods: [fdk, sart, cgls, r2gs] }\n",
    )
    .unwrap();
    let out = d.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_prism"))
        .args([
            "experiment",
            path(&suite),
            "-o",
            path(&out),
            "--slurm",
            "--cpus-per-task",
            "1",
        ])
        .env("SLURM_CONF", &cluster.conf)
        .output()
        .unwrap();
    let t = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{t}");
    assert!(
        t.contains("(1 tasks), runs") && t.contains("(4 tasks)"),
        "{t}"
    );
    let jobs: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("slurm/jobs.json")).unwrap())
            .unwrap();
    let ids: Vec<String> = jobs["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j.as_str().unwrap().to_string())
        .collect();
    assert_eq!(ids.len(), 3);
    // Wait for the report job (it runs after the arrays, whatever their outcome).
    let t0 = Instant::now();
    loop {
        let q = Command::new("squeue")
            .args(["-h", "-j", &ids.join(",")])
            .env("SLURM_CONF", &cluster.conf)
            .output()
            .unwrap();
        if String::from_utf8_lossy(&q.stdout).trim().is_empty() {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "jobs still queued after 300 s"
        );
        std::thread::sleep(Duration::from_millis(500));
    }
    let log = |f: &str| std::fs::read_to_string(out.join("slurm/logs").join(f)).unwrap_or_default();
    let report = std::fs::read_to_string(out.join("report.md"))
        .unwrap_or_else(|_| panic!("no report; collect log:\n{}", log("collect.log")));
    assert!(report.contains("(Slurm job"), "{report}");
    for task in 0..4 {
        assert!(
            log(&format!("run-{task}.log")).contains(": done"),
            "task {task}"
        );
    }
    // Every cell finished; `collect` again from the command line agrees.
    let (ok, t) = prism(&["experiment", "collect", path(&suite), "-o", path(&out)]);
    assert!(ok && t.contains("4 of 4 run cells finished"), "{t}");
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    for m in ["fdk", "sart", "cgls", "r2gs"] {
        assert!(csv.contains(&format!(",{m},{m},,mean,")), "{m}: {csv}");
    }
}
