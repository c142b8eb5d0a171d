//! End-to-end: `prism experiment` on a tiny suite (every study kind), its resumption, its refusal
//! of changed cells, and `collect`.

mod common;

use common::{path, phantom_config, prism};
use std::path::Path;

/// A suite of every study kind on 16³ phantoms with a few iterations per method.
pub fn tiny_suite(dir: &Path) -> std::path::PathBuf {
    std::fs::write(
        dir.join("p3.yaml"),
        phantom_config("p3", 30, 16, 24, &[40, 70, 100]),
    )
    .unwrap();
    std::fs::write(
        dir.join("p4.yaml"),
        phantom_config("p4", 30, 16, 24, &[40, 55, 70, 100]),
    )
    .unwrap();
    std::fs::write(dir.join("fdk.yaml"), "method: fdk\n").unwrap();
    std::fs::write(dir.join("sart.yaml"), "method: sart\niterations: 1\n").unwrap();
    let g = "iterations: 12\ninit: { n_points: 500 }\ndensify: { from: 4, until: 8, every: 4 }\neval_every: 6\n";
    std::fs::write(dir.join("r2gs.yaml"), format!("method: r2gs\n{g}")).unwrap();
    std::fs::write(
        dir.join("4dsg.yaml"),
        format!("method: 4dsg\n{g}stage2: {{ iterations: 6 }}\n"),
    )
    .unwrap();
    let suite = dir.join("suite.yaml");
    std::fs::write(
        &suite,
        r#"name: tiny
description: Every study kind on 16³ phantoms.
scenes:
  p3: { config: p3.yaml, label: Phantom }
  p2: { config: p3.yaml, set: ["channels=[{kind: mono, kev: 40}, {kind: mono, kev: 100}]"] }
  p4: { config: p4.yaml }
methods:
  fdk: { config: fdk.yaml, label: FDK }
  sart: { config: sart.yaml, label: SART }
  r2gs: { config: r2gs.yaml, label: R²-Gaussian }
  4dsg: { config: 4dsg.yaml, label: 4D-SG }
  mlp: { config: 4dsg.yaml, label: MLP, set: [stage2.curve_model.kind=mlp] }
  held: { config: 4dsg.yaml, set: ["holdout_channels=[55keV]"] }
studies:
  - { name: table, kind: table, scenes: [p3, p4], methods: [fdk, sart, r2gs, 4dsg], views: [undersampled] }
  - { name: noise, kind: noise, scenes: [p3], methods: [sart, 4dsg], views: [undersampled],
      noise: [{name: shipped}, {name: i0-1e4, set: ["noise={i0: 1.0e4}"]}], seeds: [0, 1] }
  - { name: channels, kind: channels, scenes: [p2, p3], methods: [r2gs, mlp, 4dsg], views: [undersampled] }
  - { name: curve, kind: curve-model, scenes: [p3], methods: [4dsg], views: [4, 6] }
  - { name: freeze, kind: freeze, scenes: [p3], methods: [4dsg], views: [undersampled] }
  - { name: holdout, kind: holdout, scenes: [p4], methods: [held], views: [undersampled] }
"#,
    )
    .unwrap();
    suite
}

#[test]
fn a_suite_runs_every_study_resumes_and_refuses_changed_cells() {
    let dir = tempfile::tempdir().unwrap();
    let suite = tiny_suite(dir.path());
    let out = dir.path().join("out");
    let (s, o) = (path(&suite), path(&out));
    let (ok, t) = prism(&["experiment", s, "-o", o, "--dry-run"]);
    assert!(ok, "{t}");
    // 16³ → 3 views (undersampled); the noise study's shipped seed-0 cells are the table's.
    assert!(
        t.contains("8 scene cells:") && t.contains("scenes/p3-v3-shipped-s0"),
        "{t}"
    );
    assert!(
        t.contains("runs/p3-v3-shipped-s0/4dsg.freeze  to run"),
        "{t}"
    );
    // Every scene cell's simulation is estimated before it runs.
    assert_eq!(t.matches("simulating needs ~").count(), 8, "{t}");
    // Two cells at a time, the threads split between them; every cell records it.
    let (ok, t) = prism(&["experiment", s, "-o", o, "--jobs", "2"]);
    assert!(ok, "{t}");
    assert!(
        t.contains("0 failed") && t.contains("22 of 22 run cells finished"),
        "{t}"
    );
    let record = std::fs::read_to_string(out.join("runs/p3-v3-shipped-s0/4dsg/cell.json")).unwrap();
    assert!(record.contains("\"concurrent\": 2"), "{record}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("runs made 2 at a time on "), "{report}");
    for needle in [
        "| Method | Phantom PSNR↑ | SSIM↑ | LPIPS↓ | p4 PSNR↑",
        "| Average PSNR↑",
        "4D-SG against R²-Gaussian:",
        "Equal wall time",
        "| Method | Phantom 95 % | 99 % | p4 95 % | 99 % |",
        "(noise)",
        "i0-1e4",
        " ± ",
        "Time ratio 4D-SG / R²-Gaussian:",
        "PRSD-FFFL",
        "gscnet",
        "55keV",
        "figures/table-v3-shipped-psnr-time.png",
    ] {
        assert!(
            report.contains(needle),
            "`{needle}` not in the report:\n{report}"
        );
    }
    assert!(!report.contains("Cells without results"), "{report}");
    for f in [
        "table-v3-shipped-psnr-time",
        "table-v3-shipped-p3-slices",
        "noise-psnr-noise",
        "channels-time-channels",
        "curve-p3",
        "freeze-p3",
        "holdout-p4-held-55keV-projections",
        "holdout-p4-held-55keV-psnr-views",
    ] {
        for ext in ["png", "svg"] {
            let p = out.join("figures").join(format!("{f}.{ext}"));
            assert!(
                p.is_file() && p.metadata().unwrap().len() > 500,
                "{}",
                p.display()
            );
        }
    }
    // results.csv: a row per channel and a mean row of every run; ablation variants by name.
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    assert!(
        header.starts_with("study,scene,scene_label,views,noise,seed,method"),
        "{header}"
    );
    assert!(
        csv.lines()
            .any(|l| l.starts_with("table,p4,p4,3,shipped,0,4dsg,4D-SG,,mean,false,"))
    );
    assert!(
        csv.lines()
            .any(|l| l.contains(",held,") && l.contains(",55keV,true,"))
    );
    assert_eq!(csv.lines().filter(|l| l.contains(",PRSD-")).count(), 7 * 4);
    // A second run finds every cell finished.
    let (ok, t) = prism(&["experiment", s, "-o", o]);
    assert!(ok && t.contains("0 cells run, 30 already finished"), "{t}");
    // A changed method config is refused, and redone with --force.
    std::fs::write(
        dir.path().join("sart.yaml"),
        "method: sart\niterations: 2\n",
    )
    .unwrap();
    let (ok, t) = prism(&["experiment", s, "-o", o, "--only", "sart"]);
    assert!(
        !ok && t.contains("the method's resolved config changed") && t.contains("--force"),
        "{t}"
    );
    let (ok, t) = prism(&["experiment", s, "-o", o, "--only", "sart", "--force"]);
    assert!(ok && t.contains("5 cells run"), "{t}");
    // A scene's object mask changes only the scoring: its runs are scored again from their
    // volumes, not retrained (the training log stays as it was).
    let log = out.join("runs/p3-v3-shipped-s0/4dsg/log.jsonl");
    let before = std::fs::read(&log).unwrap();
    let roi = ["--set", "scenes.p3.roi={threshold: 0.2, erode_mm: 1.0}"];
    let (ok, t) = prism(
        &[
            &[
                "experiment",
                s,
                "-o",
                o,
                "--study",
                "table",
                "--only",
                "p3",
                "--dry-run",
            ][..],
            &roi[..],
        ]
        .concat(),
    );
    assert!(
        ok && t.contains("runs/p3-v3-shipped-s0/4dsg  to score again"),
        "{t}"
    );
    let (ok, t) = prism(
        &[
            &["experiment", s, "-o", o, "--study", "table", "--only", "p3"][..],
            &roi[..],
        ]
        .concat(),
    );
    assert!(
        ok && t.contains("4 cells run") && t.contains("scoring its volumes again"),
        "{t}"
    );
    assert_eq!(std::fs::read(&log).unwrap(), before);
    let metrics =
        std::fs::read_to_string(out.join("runs/p3-v3-shipped-s0/4dsg/metrics.json")).unwrap();
    assert!(metrics.contains("\"roi\": \"object mask"), "{metrics}");
    // collect rewrites the report; --set overrides the suite itself (and is validated).
    let (ok, t) = prism(&["experiment", "collect", s, "-o", o]);
    assert!(ok && t.contains("22 of 22 run cells finished"), "{t}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("runs made in several ways: one at a time on "),
        "{report}"
    );
    let (ok, t) = prism(&[
        "experiment",
        s,
        "-o",
        o,
        "--dry-run",
        "--set",
        "studies.0.scenes=[p9]",
    ]);
    assert!(
        !ok && t.contains("`p9` is not a key of `scenes`") && t.contains("suite.yaml"),
        "{t}"
    );
}

/// The shipped suites plan from the repository alone: the CPU suite at 13 views of 64³ (its noise
/// study sharing the table's head cells, its rates study the table's 4D-SG cells, its budget
/// studies adding 2× and 4× budgets; 20 and 50 views for the curve-model study), its NAF
/// companion, the paper suite at 50 views of 256³, the real-data suite's imported scans; `--study`
/// marks the other cells as not selected, and an unknown study is refused with the known ones.
/// The plan `prism experiment <suite> -o <out> --dry-run` prints (it must succeed).
fn dry_run(suite: &Path, out: &Path) -> String {
    let (ok, t) = prism(&["experiment", path(suite), "-o", path(out), "--dry-run"]);
    assert!(ok, "{t}");
    t
}

#[test]
fn the_shipped_suites_plan_in_the_papers_regime() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let cpu = repo.join("configs/suites/cpu.yaml");
    let t = dry_run(&cpu, &out);
    assert!(
        t.contains("15 scene cells:")
            && t.contains("scenes/head-v13-shipped-s0  (64³, 13 views, 3 channels)  to run\n")
            && t.contains("scenes/ph8-v13-shipped-s0  (64³, 13 views, 8 channels)")
            && t.contains("scenes/head-v50-shipped-s0  (64³, 50 views, 3 channels)")
            && t.contains("65 run cells:")
            && t.contains("runs/abdomen-v13-shipped-s0/4dsg-r2rates  to run\n")
            && t.contains("runs/head-v13-shipped-s0/r2gs-x2  to run\n")
            && t.contains("runs/chest-v13-shipped-s0/4dsg-x4  to run\n")
            && t.contains("runs/head-v13-i0-1e4-s0/4dsg  to run\n")
            && t.contains("runs/ph8-v13-shipped-s0/4dsg-quarter  to run\n")
            && !t.contains("naf"),
        "{t}"
    );
    assert!(!out.exists(), "a dry run creates nothing");
    let (ok, t) = prism(&[
        "experiment",
        path(&cpu),
        "-o",
        path(&out),
        "--dry-run",
        "--study",
        "table",
    ]);
    assert!(ok, "{t}");
    assert!(
        t.contains("runs/head-v13-shipped-s0/4dsg  to run\n")
            && t.contains("runs/head-v13-i0-1e4-s0/4dsg  to run (not selected)")
            && t.contains(
                "scenes/ph2-v13-shipped-s0  (64³, 13 views, 2 channels)  to run (not selected)"
            ),
        "{t}"
    );
    let (ok, t) = prism(&[
        "experiment",
        path(&cpu),
        "-o",
        path(&out),
        "--study",
        "tabel",
    ]);
    assert!(
        !ok && t.contains("no study `tabel` (the suite has: table, noise, channels"),
        "{t}"
    );
    let t = dry_run(&repo.join("configs/suites/cpu-naf.yaml"), &out);
    assert!(
        t.contains("2 scene cells:")
            && t.contains("6 run cells:")
            && t.contains("runs/ph3-v13-shipped-s0/naf  to run\n"),
        "{t}"
    );
    // The spectral suite: six interleaved scenes at 13 angles per channel (39 for 3 channels, 52
    // for 4 tube voltages, 104 for the abdomen's 8), their every-channel reference at the same
    // angles, and two low-dose levels (with the Gaussian methods' other data terms beside
    // their own); the joint classic baseline (TNV) beside SART; 4D-SG with R²-Gaussian's rates,
    // and the basis head on the three scenes whose channels it can form (with a short stage 1 on
    // all six, two materials on mixed kVp); mixed kVp interleaved at two more seeds; 4D-SG at 2×
    // its budget at low dose.
    let t = dry_run(&repo.join("configs/suites/spectral.yaml"), &out);
    assert!(
        t.contains("20 scene cells:")
            && t.contains("scenes/mixed-v65-interleaved-s2  (64³, 65 views, 5 channels)")
            && t.contains("scenes/chest-v39-interleaved-s0  (64³, 39 views, 3 channels)")
            && t.contains("scenes/abdomen-v104-interleaved-s0  (64³, 104 views, 8 channels)")
            && t.contains("scenes/kvp-v52-interleaved-s0  (64³, 52 views, 4 channels)")
            && t.contains("scenes/head-v39-shipped-s0  (64³, 39 views, 3 channels)")
            && t.contains("scenes/pcct-v13-i0-3e3-s0  (64³, 13 views, 4 channels)")
            && t.contains("142 run cells:")
            && t.contains("runs/mixed-v65-shipped-s1/4dsg-r2rates-res-s1  to run\n")
            && t.contains("runs/kvp-v52-interleaved-s0/4dsg-basis-r2rates-s1  to run\n")
            && t.contains("runs/head-v13-i0-1e4-s0/4dsg-x2  to run\n")
            && t.contains("runs/head-v39-interleaved-s0/r2gs  to run\n")
            && t.contains("runs/head-v39-shipped-s0/4dsg-r2rates-res  to run\n")
            && t.contains("runs/pcct-v13-i0-1e4-s0/tnv  to run\n")
            && t.contains("runs/pcct-v13-i0-3e3-s0/4dsg-counts  to run\n")
            && t.contains("runs/head-v13-i0-1e4-s0/r2gs-wls  to run\n")
            && t.contains("runs/kvp-v52-shipped-s0/4dsg-basis-r2rates  to run\n"),
        "{t}"
    );
    let t = dry_run(&repo.join("configs/suites/paper.yaml"), &out);
    assert!(
        t.contains("6 scene cells:")
            && t.contains("scenes/abdomen-v50-shipped-s0  (256³, 50 views, 8 channels)")
            && t.contains("36 run cells:")
            && t.contains("runs/chest-v50-shipped-s0/naf  to run\n"),
        "{t}"
    );
    // The real-data suite: the bird scan imported (fan beam, one 512 × 512 slice), cut to 60 views
    // on Cueva et al.'s geometry and to 30, 60 and 120 on the scan's own, every method on each;
    // its studies: the sweeps on the dTV protocol (one study at a second seed, its own scene
    // cell) and the tooth (parallel beam, two rows) at 23 and 45 views.
    let t = dry_run(&repo.join("configs/suites/real.yaml"), &out);
    assert!(
        t.contains("4 scene cells:")
            && t.contains("scenes/bird-dtv-v60-shipped-s0  (512×512×1, 60 views, 3 channels)  to run\n      importing needs ~")
            && t.contains("scenes/bird-v120-shipped-s0  (512×512×1, 120 views, 3 channels)")
            && t.contains("28 run cells:")
            && t.contains("runs/bird-v30-shipped-s0/4dsg  to run\n")
            && t.contains("runs/bird-v120-shipped-s0/naf  to run\n")
            && t.contains("runs/bird-dtv-v60-shipped-s0/tnv  to run\n"),
        "{t}"
    );
    let t = dry_run(&repo.join("configs/suites/real-studies.yaml"), &out);
    assert!(
        t.contains("9 scene cells:")
            && t.contains("scenes/bird-v30-shipped-s0  (512×512×1, 30 views, 3 channels)")
            && t.contains("scenes/tooth-v23-shipped-s0  (512×512×2, 23 views, 1 channels)")
            && t.contains("70 run cells:")
            && t.contains("runs/bird-dtv-v60-shipped-s1/4dsg-dtv512x20-60k-w-r0  to run\n")
            && t.contains("runs/bird-dtv-v60-shipped-s3/4dsg-dtv512x20-60k-w  to run\n")
            && t.contains("runs/bird-dtv-v60-shipped-s2/4dsg-dtv512x20-60k-w-r0-rms  to run\n")
            && t.contains("runs/bird-v120-shipped-s0/4dsg-rms  to run\n")
            && t.contains("runs/bird-dtv-v60-shipped-s0/4dsg-tv512x10  to run\n")
            && t.contains("runs/bird-dtv-v60-shipped-s0/4dsg-dtv512x20-60k-w-r0  to run\n")
            && t.contains("runs/bird-dtv-v60-shipped-s0/4dsg-dtv512x20-60k-w  to run\n")
            && t.contains("runs/bird-dtv-v60-shipped-s0/dtv-0.15-i1000  to run\n")
            && t.contains("runs/tooth-v45-shipped-s0/r2gs  to run\n"),
        "{t}"
    );
}

/// `jobs` beyond the machine's cores runs one cell per core, says so, and records what ran.
#[test]
fn more_jobs_than_cores_are_capped_at_the_cores() {
    let dir = tempfile::tempdir().unwrap();
    let suite = tiny_suite(dir.path());
    let out = dir.path().join("out");
    let (ok, t) = prism(&[
        "experiment",
        path(&suite),
        "-o",
        path(&out),
        "--study",
        "table",
        "--only",
        "fdk",
        "--jobs",
        "100000",
    ]);
    assert!(ok, "{t}");
    let cores = std::thread::available_parallelism().unwrap().get();
    assert!(
        t.contains(&format!("jobs 100000: this machine has {cores} cores")),
        "{t}"
    );
    let record: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("runs/p3-v3-shipped-s0/fdk/cell.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        record["execution"]["concurrent"].as_u64(),
        Some(cores as u64),
        "{record}"
    );
}

/// `--html`: `report.html` with its viewer's data beside it and nothing fetched from a network,
/// used in headless Chromium by `tests/browser/report_page.py` (the z slider, a channel switch,
/// the linked cursor and the residual view change what is drawn; no console error); and
/// `prism report --html` over two runs and their scene. The browser part is skipped with a message
/// where Chromium, chromedriver or Selenium is missing, unless `PRISM_REQUIRE_BROWSER` is set
/// (`.ci/run` installs them and sets it). `PRISM_SCREENSHOTS=<dir>` keeps the screenshots.
#[test]
fn the_html_report_is_browsable_offline() {
    let dir = tempfile::tempdir().unwrap();
    let suite = tiny_suite(dir.path());
    let out = dir.path().join("out");
    let (ok, t) = prism(&[
        "experiment",
        path(&suite),
        "-o",
        path(&out),
        "--study",
        "table",
        "--html",
    ]);
    assert!(ok, "{t}");
    assert!(
        t.contains("report.html (") && t.contains("report-data"),
        "{t}"
    );
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        html.contains("<table>")
            && html.contains("id=\"slice-viewer\"")
            && html.contains("<img src=\"data:image/png;base64,"),
        "{html}"
    );
    for remote in [
        "src=\"http",
        "href=\"http",
        "url(http",
        "src=\"//",
        "rel=\"stylesheet\"",
    ] {
        assert!(!html.contains(remote), "the page loads `{remote}…`");
    }
    // One set per finished Table II scene cell (the noisy cells did not run): p3 and p4.
    let sets: serde_json::Value = serde_json::from_str(
        html.split("window.PRISM_SETS = ")
            .nth(1)
            .and_then(|s| s.split(";\n").next())
            .unwrap(),
    )
    .unwrap();
    assert_eq!(sets.as_array().unwrap().len(), 2, "{sets}");
    let script = std::fs::read_to_string(out.join("report-data/set-1.js")).unwrap();
    let json = script
        .strip_prefix("PrismViewer.add(1, ")
        .and_then(|s| s.trim_end().strip_suffix(");"))
        .unwrap();
    let set: serde_json::Value = serde_json::from_str(json).unwrap();
    assert_eq!(set["title"], "p4, 3 views, noise shipped");
    assert_eq!(set["shape"], serde_json::json!([16, 16, 16]));
    assert_eq!(set["channels"].as_array().unwrap().len(), 4);
    assert!(
        set["channels"][0]["reference"]
            .as_str()
            .is_some_and(|u| u.starts_with("data:image/png;base64,")),
        "the scene's reference is shown"
    );
    let methods: Vec<&str> = set["methods"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["label"].as_str().unwrap())
        .collect();
    assert_eq!(methods, ["FDK", "SART", "R²-Gaussian", "4D-SG"]);
    for m in set["methods"].as_array().unwrap() {
        for key in ["images", "residuals"] {
            assert!(
                m[key].as_array().unwrap().iter().all(|u| u
                    .as_str()
                    .is_some_and(|u| u.starts_with("data:image/png;base64,"))),
                "{}",
                m["label"]
            );
        }
    }
    browse(&out.join("report.html"), dir.path());

    let cell = out.join("runs/p3-v3-shipped-s0");
    let page = dir.path().join("runs.html");
    let (ok, t) = prism(&[
        "report",
        path(&cell.join("sart")),
        path(&cell.join("4dsg")),
        "--html",
        path(&page),
        "--scene",
        path(&out.join("scenes/p3-v3-shipped-s0")),
    ]);
    assert!(ok, "{t}");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(
        html.contains("PSNR against time") && html.contains("runs-data/set-0.js"),
        "{html}"
    );
    assert!(dir.path().join("runs-data/psnr-time.png").exists());
}

/// Use `page` in headless Chromium (tests/browser/report_page.py); see the test above.
fn browse(page: &Path, dir: &Path) {
    let shots = std::env::var_os("PRISM_SCREENSHOTS")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| dir.join("screenshots"));
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/browser/report_page.py"
    );
    let o = std::process::Command::new("python3")
        .args([script, path(page), "--screenshots", path(&shots)])
        .output()
        .expect("python3 runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    if o.status.code() == Some(2) {
        assert!(
            std::env::var_os("PRISM_REQUIRE_BROWSER").is_none(),
            "PRISM_REQUIRE_BROWSER is set but no browser runs: {text}"
        );
        eprintln!("skipped the browser check: {text}");
        return;
    }
    assert!(o.status.success(), "{text}");
    assert!(shots.join("3-viewer-residual.png").exists(), "{text}");
}
