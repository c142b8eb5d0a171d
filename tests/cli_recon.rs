//! End-to-end: simulate a small scene, reconstruct it with each classic method (TV included) through the
//! `prism` binary, and check the run directory and the `metrics.json` contract.

mod common;

use common::{path, prism, simulated};

#[test]
fn recon_writes_volumes_config_and_metrics() {
    let (dir, scene) = simulated("tiny-recon", 24, 24, 32, &[50, 90]);
    for (method, extra) in [
        ("fdk", ""),
        ("sart", "iterations: 2\n"),
        ("cgls", "iterations: 3\n"),
        ("tv", "iterations: 20\n"),
    ] {
        let rc = dir.path().join(format!("{method}.yaml"));
        std::fs::write(&rc, format!("method: {method}\n{extra}")).unwrap();
        let run = dir.path().join(format!("run-{method}"));
        let (ok, t) = prism(&["recon", path(&rc), "-s", path(&scene), "-o", path(&run)]);
        assert!(ok, "{method}: {t}");
        for f in [
            "50keV.npy",
            "90keV.npy",
            "config.resolved.yaml",
            "metrics.json",
        ] {
            assert!(run.join(f).is_file(), "{method}: {f} missing");
        }
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("metrics.json")).unwrap())
                .unwrap();
        assert_eq!(m["method"], method);
        assert_eq!(m["scene"], "tiny-recon");
        assert!(m["wall_s"].as_f64().unwrap() > 0.0);
        let channels = m["channels"].as_array().unwrap();
        assert_eq!(channels.len(), 2);
        for c in channels {
            let psnr = c["psnr"].as_f64().unwrap();
            let ssim = c["ssim"].as_f64().unwrap();
            // A 24-view reconstruction of the phantom is far from noise (< 10 dB) and from exact.
            assert!((12.0..60.0).contains(&psnr), "{method}: psnr {psnr}");
            assert!((0.0..=1.0).contains(&ssim), "{method}: ssim {ssim}");
            assert!(c["label"].is_string());
            assert_eq!(c["coordinate"]["kind"], "energy");
        }
        assert!(m["mean"]["psnr"].as_f64().is_some() && m["mean"]["ssim"].as_f64().is_some());
    }
    // A used run directory is refused without --force and replaced with it; a file the run
    // did not write survives.
    let run = dir.path().join("run-fdk");
    std::fs::write(run.join("notes.txt"), "mine").unwrap();
    let rc = dir.path().join("fdk.yaml");
    let (ok, t) = prism(&["recon", path(&rc), "-s", path(&scene), "-o", path(&run)]);
    assert!(
        !ok && t.contains("--force") && t.contains("not empty"),
        "{t}"
    );
    let (ok, t) = prism(&[
        "recon",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&run),
        "--force",
    ]);
    assert!(ok, "{t}");
    assert!(run.join("notes.txt").is_file() && run.join("run.json").is_file());
    // The evaluation protocol's options reach metrics.json; both PSNR conventions are printed.
    let (ok, t) = prism(&[
        "recon",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&run),
        "--force",
        "--eval-grid",
        "32",
        "--eval-slices",
        "all",
    ]);
    assert!(ok && t.contains("PSNR (volume / slices)"), "{t}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(m["protocol"]["grid"], "resized to 32³ (trilinear)");
    assert_eq!(m["protocol"]["slices"], "all");
    assert!(m["channels"][0]["lpips"].is_null() && m["mean"]["psnr_slices"].is_f64());
    for (flag, value, needle) in [
        ("--eval-grid", "1", "--eval-grid"),
        (
            "--lpips-weights",
            "/nonexistent/w.safetensors",
            "/nonexistent/w.safetensors",
        ),
    ] {
        let (ok, t) = prism(&[
            "recon",
            path(&rc),
            "-s",
            path(&scene),
            "-o",
            path(&run),
            "--force",
            flag,
            value,
        ]);
        assert!(!ok && t.contains(needle), "{flag}: {t}");
    }
}

#[test]
fn recon_bad_input_names_the_field() {
    let (dir, scene) = simulated("tiny-recon", 24, 24, 32, &[50, 90]);
    for (body, field) in [
        ("method: sart\niterations: 0\n", "iterations"),
        ("method: sart\nlambda: -1\n", "lambda"),
        ("method: fdk\nfilter: triangle\n", "filter"),
        ("method: magic\n", "method"),
    ] {
        let rc = dir.path().join("bad.yaml");
        std::fs::write(&rc, body).unwrap();
        let run = dir.path().join("run-bad");
        let (ok, t) = prism(&["recon", path(&rc), "-s", path(&scene), "-o", path(&run)]);
        assert!(!ok, "{body} should fail");
        assert!(
            t.contains(field) && t.contains("bad.yaml"),
            "{field} not named: {t}"
        );
        assert!(!run.join("metrics.json").exists());
    }
    // `--set` overrides the config, is validated like the file, and lands in
    // config.resolved.yaml.
    let rc = dir.path().join("sart.yaml");
    std::fs::write(&rc, "method: sart\niterations: 2\n").unwrap();
    let run = dir.path().join("run-set");
    let (ok, t) = prism(&[
        "recon",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&run),
        "--set",
        "iterations=0",
    ]);
    assert!(
        !ok && t.contains("iterations") && t.contains("--set iterations=0"),
        "{t}"
    );
    let (ok, t) = prism(&[
        "recon",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&run),
        "--set",
        "iterations=1",
    ]);
    assert!(ok, "{t}");
    let resolved = std::fs::read_to_string(run.join("config.resolved.yaml")).unwrap();
    assert!(resolved.contains("iterations: 1"), "{resolved}");
}

/// A temporary directory holding a simulated three-channel scene (in `<dir>/scene`).
fn spectral_scene() -> (tempfile::TempDir, std::path::PathBuf) {
    simulated("tiny-spectral", 16, 24, 32, &[50, 70, 90])
}

#[test]
fn four_dsg_with_a_held_out_channel_then_queries() {
    let (dir, scene) = spectral_scene();
    let rc = dir.path().join("4dsg.yaml");
    std::fs::write(
        &rc,
        "method: 4dsg\niterations: 15\neval_every: 0\ninit: {n_points: 300, threshold: 0.05, \
         density_rescale: 0.15, neighbours: 3}\ndensify: null\nholdout_channels: [70keV]\n\
         stage2: {iterations: 10, curve_model: {width: 8, depth: 1}}\n",
    )
    .unwrap();
    let run = dir.path().join("run");
    let (ok, t) = prism(&["recon", path(&rc), "-s", path(&scene), "-o", path(&run)]);
    assert!(ok, "{t}");
    for f in [
        "50keV.npy",
        "70keV.npy",
        "90keV.npy",
        "metrics.json",
        "holdout.json",
        "log.jsonl",
        "train.json",
        "gaussians.safetensors",
        "gaussians.ply",
        "geometry.safetensors",
    ] {
        assert!(run.join(f).is_file(), "{f} missing");
    }
    // Continuing from the stage-1 checkpoint gives the same volumes; the option is refused for
    // a classic method.
    let again = dir.path().join("again");
    let (ok, t) = prism(&[
        "recon",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&again),
        "--from-geometry",
        path(&run),
    ]);
    assert!(ok, "{t}");
    assert!(
        std::fs::read(run.join("90keV.npy")).unwrap()
            == std::fs::read(again.join("90keV.npy")).unwrap()
    );
    let sart = dir.path().join("sart.yaml");
    std::fs::write(
        &sart,
        "method: sart
iterations: 2
",
    )
    .unwrap();
    let (ok, t) = prism(&[
        "recon",
        path(&sart),
        "-s",
        path(&scene),
        "-o",
        path(&again),
        "--from-geometry",
        path(&run),
    ]);
    assert!(!ok && t.contains("--from-geometry"), "{t}");
    let h: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("holdout.json")).unwrap()).unwrap();
    assert_eq!(h[0]["label"], "70keV");
    assert!(h[0]["proj_psnr"].as_f64().unwrap().is_finite());
    let out = dir.path().join("q.npy");
    let (ok, t) = prism(&["query", path(&run), "--coordinate", "60", "-o", path(&out)]);
    assert!(ok && out.is_file(), "{t}");
    // The output exists: replaced only with --force.
    let (ok, t) = prism(&[
        "query",
        path(&run),
        "--tau",
        "0.5",
        "--projections",
        "-o",
        path(&out),
    ]);
    assert!(!ok && t.contains("--force"), "{t}");
    let (ok, t) = prism(&[
        "query",
        path(&run),
        "--tau",
        "0.5",
        "--projections",
        "-o",
        path(&out),
        "--force",
    ]);
    assert!(ok, "{t}");
    let (ok, t) = prism(&["query", path(&run), "--coordinate", "120", "-o", path(&out)]);
    assert!(!ok && t.contains("extrapolate"), "{t}");
    // A non-finite τ is refused, with or without --extrapolate.
    for tau in ["nan", "inf"] {
        let (ok, t) = prism(&[
            "query",
            path(&run),
            "--tau",
            tau,
            "--extrapolate",
            "-o",
            path(&out),
        ]);
        assert!(!ok && t.contains("finite"), "{t}");
    }
    // The report marks the predicted channel and lists the volumes.
    let (ok, t) = prism(&["report", path(&run)]);
    assert!(ok, "{t}");
    assert!(t.contains("| 70keV |") && t.contains("* |"), "{t}");
    assert!(t.contains(path(&run.join("90keV.npy"))), "{t}");
}

#[test]
fn ablation_runs_every_variant_from_one_stage_one() {
    let (dir, scene) = spectral_scene();
    let rc = dir.path().join("4dsg.yaml");
    std::fs::write(
        &rc,
        "method: 4dsg\niterations: 10\neval_every: 0\ninit: {n_points: 200, threshold: 0.05, \
         density_rescale: 0.15, neighbours: 3}\ndensify: null\n\
         stage2: {iterations: 4, curve_model: {width: 8, depth: 1, table_size: 64}}\n",
    )
    .unwrap();
    let out = dir.path().join("ablation");
    let (ok, t) = prism(&[
        "ablate",
        "curve-model",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&out),
    ]);
    assert!(ok, "{t}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("ablation.json")).unwrap()).unwrap();
    let rows = report["rows"].as_array().unwrap();
    let names: Vec<&str> = rows
        .iter()
        .map(|r| r["variant"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["gscnet", "mlp"]);
    let stage1_s = report["stage1_s"].as_f64().unwrap();
    for r in rows {
        let v = out.join(r["variant"].as_str().unwrap());
        assert!(v.join("metrics.json").is_file() && v.join("50keV.npy").is_file());
        assert!(r["psnr"].as_f64().unwrap().is_finite());
        // Each variant's run includes the shared stage 1: its log starts with the geometry
        // records and its time counts the geometry's.
        let log = std::fs::read_to_string(v.join("log.jsonl")).unwrap();
        let stages: Vec<serde_json::Value> = log
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(stages.first().unwrap()["stage"], "geometry");
        assert_eq!(stages.last().unwrap()["stage"], r["curve_model"]);
        assert!(r["train_s"].as_f64().unwrap() >= stage1_s);
    }
    assert!(t.contains("| gscnet |") && t.contains("| mlp |"), "{t}");
    // The shared stage 1 leaves its checkpoint; a second study can start from it, and gives the
    // same variants the same scores.
    assert!(out.join("geometry/geometry.safetensors").is_file());
    let again = dir.path().join("again");
    let (ok, t) = prism(&[
        "ablate",
        "curve-model",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&again),
        "--from-geometry",
        path(&out.join("geometry")),
    ]);
    assert!(ok, "{t}");
    let psnrs = |d: &std::path::Path| -> Vec<f64> {
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join("ablation.json")).unwrap())
                .unwrap();
        r["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["psnr"].as_f64().unwrap())
            .collect()
    };
    assert_eq!(psnrs(&out), psnrs(&again));
    // Only `4dsg` has a stage 2 to ablate.
    std::fs::write(&rc, "method: sart\niterations: 2\n").unwrap();
    let (ok, t) = prism(&[
        "ablate",
        "freeze",
        path(&rc),
        "-s",
        path(&scene),
        "-o",
        path(&out),
    ]);
    assert!(
        !ok && t.contains("method") && t.contains("4dsg.yaml"),
        "{t}"
    );
}

/// `prism info` and `prism recon -s` take an R²-Gaussian case folder (`meta_data.json`) as a
/// one-channel scene.
#[test]
fn an_r2_gaussian_case_folder_is_a_scene() {
    let dir = tempfile::tempdir().unwrap();
    let case = dir.path().join("case");
    prism_domain::testing::write_r2_case(&case);
    let (ok, t) = prism(&["info", path(&case)]);
    assert!(ok && t.contains("r2"), "{t}");
    // Its 4×3×2 reference is too small to score (SSIM's 11² window): reconstruct without it.
    let meta = case.join(prism_domain::scene::R2_META_FILE);
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&meta).unwrap()).unwrap();
    m.as_object_mut().unwrap().remove("vol");
    std::fs::write(&meta, m.to_string()).unwrap();
    std::fs::remove_file(case.join("vol_gt.npy")).unwrap();
    let (ok, t) = prism(&["info", path(&case)]);
    assert!(ok && t.contains("r2"), "{t}");
    // SART: the case's three training views span 2 rad, too short a scan for FDK.
    let sart = dir.path().join("sart.yaml");
    std::fs::write(&sart, "method: sart\niterations: 1\n").unwrap();
    let run = dir.path().join("run");
    let (ok, t) = prism(&["recon", path(&sart), "-s", path(&case), "-o", path(&run)]);
    assert!(ok && run.join("r2.npy").is_file(), "{t}");
}

/// `recon --dry-run` itemises the estimated peak memory and writes nothing; a run whose
/// estimate exceeds the memory available is refused before it starts, unless `--allow-memory`
/// (here: a densification cap of 10¹² Gaussians).
#[test]
fn recon_estimates_its_memory_and_refuses_what_cannot_fit() {
    let (dir, scene) = common::simulated("mem", 4, 16, 16, &[70]);
    let cfg = dir.path().join("r2gs.yaml");
    std::fs::write(
        &cfg,
        "method: r2gs\niterations: 4\ninit: { n_points: 200 }\n\
         densify: { from: 1, until: 3, every: 1, max_gaussians: 1000 }\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let args = |extra: &[&'static str]| {
        let mut a = vec!["recon", path(&cfg), "-s", path(&scene), "-o", path(&out)];
        a.extend_from_slice(extra);
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let run = |a: Vec<String>| prism(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let (ok, t) = run(args(&["--dry-run"]));
    assert!(ok, "{t}");
    for needle in [
        "1000 Gaussians (at the densification cap; 200 at the start)",
        "the scene: projections (1 × 6 views × 16×16)",
        "estimated peak",
    ] {
        assert!(t.contains(needle), "`{needle}` not in:\n{t}");
    }
    assert!(!out.exists(), "a dry run writes nothing");
    let huge = ["--set", "densify.max_gaussians=1000000000000"];
    let (ok, t) = run(args(&huge));
    assert!(
        !ok && t.contains("--allow-memory") && t.contains("r2gs"),
        "{t}"
    );
    assert!(!out.exists(), "a refused run writes nothing");
    // Overridden, the run goes ahead (and stays small: the cap is never reached).
    let (ok, t) = run(args(&[huge[0], huge[1], "--allow-memory"]));
    assert!(ok, "{t}");
}

/// `prism bench iteration` measures the window after densification: one row per channel with
/// the Gaussian count of `train.json`, allocations seen by the counting allocator, and the
/// must-move bytes of its formula (36·11·K + 12·pixels + 8·patch voxels).
#[test]
fn bench_iteration_reports_allocations_against_the_traffic_bound() {
    let (dir, scene) = simulated("iter", 4, 16, 16, &[40, 70]);
    let cfg = dir.path().join("r2gs.yaml");
    std::fs::write(
        &cfg,
        "method: r2gs\niterations: 12\ninit: { n_points: 300 }\n\
         densify: { from: 1, until: 4, every: 2 }\nloss: { tv_patch: 8 }\n",
    )
    .unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(["bench", "iteration", path(&cfg), "-s", path(&scene)])
        .args(["--window", "5"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["stages"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "{v}");
    for r in rows {
        let k = r["gaussians"].as_f64().unwrap();
        assert!(k > 0.0, "{r}");
        let must = 36.0 * 11.0 * k + 12.0 * 16.0 * 16.0 + 8.0 * 512.0;
        assert_eq!(r["must_move_bytes"].as_f64().unwrap(), must, "{r}");
        assert!(r["allocated_bytes"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["allocations"].as_f64().unwrap() >= 1.0, "{r}");
        assert!(r["iteration_s"].as_f64().unwrap() > 0.0, "{r}");
    }
    assert!(
        v["copy_bandwidth_bytes_per_s"].as_f64().unwrap() > 1e8,
        "{v}"
    );
    // A window reaching into densification is refused.
    let (ok, t) = prism(&[
        "bench",
        "iteration",
        path(&cfg),
        "-s",
        path(&scene),
        "--window",
        "10",
    ]);
    assert!(!ok && t.contains("--window 10"), "{t}");
}

/// `prism bench scaling --quick` sweeps the chosen axes from the base point, each (point, method)
/// once in a process of its own: R²-Gaussian and NAF one timed stage per channel, 4D-SG two,
/// the Gaussian count the point's (densification off), a peak RSS and an estimate for each;
/// power laws for the swept series; log-log figures. A missing config folder is named.
#[test]
fn bench_scaling_sweeps_each_axis_and_fits_power_laws() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scaling");
    let configs = concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_prism"))
        .args([
            "bench", "scaling", "--quick", "--warmup", "1", "--window", "2",
        ])
        .args(["--axes", "gaussians,channels", "--configs", configs])
        .args(["-o", path(&out)])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("scaling.json")).unwrap()).unwrap();
    let ms = v["measurements"].as_array().unwrap();
    // 2 axes × 2 values, the base shared: 3 points × 3 methods, less NAF at K = 500.
    assert_eq!(ms.len(), 8, "{v}");
    assert!(v["failed"].as_array().unwrap().is_empty(), "{v}");
    for m in ms {
        let channels = m["point"]["channels"].as_u64().unwrap() as usize;
        let stages = m["stages"].as_array().unwrap();
        let expected = if m["method"] == "4dsg" { 2 } else { channels };
        assert_eq!(stages.len(), expected, "{m}");
        for s in stages {
            assert!(s["iteration_s"].as_f64().unwrap() > 0.0, "{m}");
            if m["method"] != "naf" {
                assert_eq!(s["gaussians"], m["point"]["gaussians"], "{m}");
            }
        }
        assert!(m["peak_rss_bytes"].as_f64().unwrap() > 1e6, "{m}");
        assert!(m["estimate_bytes"].as_f64().unwrap() > 1e6, "{m}");
    }
    let fits = v["fits"].as_array().unwrap();
    for (axis, series) in [
        ("gaussians", "time r2gs"),
        ("gaussians", "time 4dsg stage 2"),
        ("channels", "time naf"),
        ("channels", "peak 4dsg"),
    ] {
        assert!(
            fits.iter()
                .any(|f| f["axis"] == axis && f["series"] == series && f["exponent"].is_f64()),
            "{axis} {series}: {v}"
        );
    }
    for stem in ["scaling-time", "scaling-memory"] {
        assert!(
            std::fs::metadata(out.join(format!("{stem}.png")))
                .unwrap()
                .len()
                > 1000
        );
        let svg = std::fs::read_to_string(out.join(format!("{stem}.svg"))).unwrap();
        assert!(
            svg.contains("against Gaussians") && svg.contains("r2gs"),
            "{stem}"
        );
    }
    let (ok, t) = prism(&["bench", "scaling", "--quick", "--configs", path(dir.path())]);
    assert!(!ok && t.contains("phantom-4mono.yaml: not found"), "{t}");
}

/// Ctrl-C (SIGINT) during a Gaussian run: the current step finishes, the run's state is saved
/// beside the output directory, nothing is published and the exit status is 130; the same
/// command with `--resume` finishes the run and removes the checkpoint; `--resume` of a classic
/// method is refused.
#[test]
fn sigint_saves_a_checkpoint_and_resume_finishes_the_run() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let (dir, scene) = simulated("sigint", 24, 24, 32, &[40, 70]);
    let rc = dir.path().join("r2gs.yaml");
    std::fs::write(
        &rc,
        "method: r2gs\niterations: 400\ninit:\n  n_points: 500\neval_every: 0\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let args = ["recon", path(&rc), "-s", path(&scene), "-o", path(&out)];
    let child = Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(args)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    // The handler is installed before the run creates its staging directory.
    let staging = dir.path().join(".run.partial");
    let start = Instant::now();
    while !staging.exists() {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "the run never started"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // The shell's built-in `kill` (no procps needed).
    let kill = format!("kill -INT {}", child.id());
    assert!(
        Command::new("sh")
            .args(["-c", &kill])
            .status()
            .unwrap()
            .success()
    );
    let done = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    assert_eq!(done.status.code(), Some(130), "{err}");
    let ckpt = dir.path().join("run.resume.safetensors");
    assert!(
        err.contains("interrupted in `r2gs 40keV` after iteration")
            && err.contains("run.resume.safetensors")
            && err.contains("--resume"),
        "{err}"
    );
    assert!(ckpt.is_file() && !out.exists() && !staging.exists());

    // Starting afresh warns that it will replace the checkpoint; resuming finishes the run.
    let (ok, t) = prism(&[args.as_slice(), &["--resume"]].concat());
    assert!(ok, "{t}");
    assert!(t.contains("resuming r2gs 40keV after iteration"), "{t}");
    let train: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("train.json")).unwrap()).unwrap();
    assert_eq!(train["stages"][1]["iterations"], 400);
    assert!(
        !ckpt.exists(),
        "the checkpoint is removed with the published run"
    );

    let fdk = dir.path().join("fdk.yaml");
    std::fs::write(&fdk, "method: fdk\n").unwrap();
    let (ok, t) = prism(&[
        "recon",
        path(&fdk),
        "-s",
        path(&scene),
        "-o",
        path(&dir.path().join("f")),
        "--resume",
    ]);
    assert!(!ok && t.contains("--resume") && t.contains("`fdk`"), "{t}");
}
