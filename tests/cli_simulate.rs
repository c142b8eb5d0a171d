//! End-to-end: the `prism` binary simulates a small scene, inspects it, and refuses bad input
//! with an error that names the file and the field, leaving nothing half-written.

mod common;

use common::prism;
use std::path::Path;

/// A two-channel scene config whose detector is not square (24 rows × 32 cols).
fn tiny() -> String {
    common::phantom_config("tiny-cli", 5, 16, 32, &[40, 100])
        .replace(
            "rows: 32, cols: 32, size_mm: [512.0, 512.0]",
            "rows: 24, cols: 32, size_mm: [512.0, 384.0]",
        )
        .replace("name: tiny-cli\n", "name: tiny-cli\nseed: 1\n")
}

fn write(dir: &Path, name: &str, body: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, body).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn simulate_then_info() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(dir.path(), "tiny.yaml", &tiny());
    let out = dir.path().join("scene");
    let (ok, t) = prism(&["simulate", &cfg, "-o", out.to_str().unwrap()]);
    assert!(ok, "{t}");
    for f in [
        "scene.yaml",
        "projections.npy",
        "availability.npy",
        "references.npy",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let (ok, t) = prism(&["info", out.to_str().unwrap()]);
    assert!(ok, "{t}");
    for needle in [
        "tiny-cli",
        "24 rows × 32 cols",
        "40keV",
        "100keV",
        "5 train, 2 test",
    ] {
        assert!(t.contains(needle), "`{needle}` not in:\n{t}");
    }
    // The config is recorded verbatim in the scene's provenance.
    let yaml = std::fs::read_to_string(out.join("scene.yaml")).unwrap();
    assert!(yaml.contains("name: tiny-cli"));
}

#[test]
fn bad_input_fails_cleanly_and_names_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene");
    let cases = [
        (
            tiny().replace("dso: 1000.0", "dso: -1000.0"),
            "geometry.dso",
        ),
        (tiny().replace("kev: 100", "kev: 400"), "channels[1].kev"),
        (
            tiny().replace("kind: mono, kev: 40", "kind: laser, kev: 40"),
            "channels",
        ),
        (
            tiny().replace("rows: 24", "rows: 0"),
            "geometry.detector.rows",
        ),
    ];
    for (body, field) in cases {
        let cfg = write(dir.path(), "bad.yaml", &body);
        let (ok, t) = prism(&["simulate", &cfg, "-o", out.to_str().unwrap()]);
        assert!(!ok, "expected failure for {field}");
        assert!(t.contains(field), "`{field}` not named in: {t}");
        assert!(
            t.contains("bad.yaml"),
            "the config file is not named in: {t}"
        );
        assert!(!out.exists(), "nothing may be written on failure");
    }
    let (ok, t) = prism(&[
        "simulate",
        "/nonexistent/x.yaml",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && t.contains("/nonexistent/x.yaml"), "{t}");
    let (ok, t) = prism(&["info", dir.path().join("nowhere").to_str().unwrap()]);
    assert!(!ok && t.contains("nowhere"), "{t}");
}

#[test]
fn set_overrides_change_the_scene_and_are_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(dir.path(), "tiny.yaml", &tiny());
    let out = dir.path().join("scene");
    let o = out.to_str().unwrap();
    let (ok, t) = prism(&[
        "simulate",
        &cfg,
        "-o",
        o,
        "--set",
        "geometry.views=3",
        "--set",
        "channels.1.kev=70",
    ]);
    assert!(ok, "{t}");
    let (ok, t) = prism(&["info", o]);
    assert!(
        ok && t.contains("3 train, 2 test") && t.contains("70keV"),
        "{t}"
    );
    let yaml = std::fs::read_to_string(out.join("scene.yaml")).unwrap();
    assert!(
        yaml.contains("- geometry.views=3") && yaml.contains("- channels.1.kev=70"),
        "overrides not recorded in the provenance:\n{yaml}"
    );
    // A bad override is refused naming the file, the field and the override.
    let bad = dir.path().join("bad");
    let (ok, t) = prism(&[
        "simulate",
        &cfg,
        "-o",
        bad.to_str().unwrap(),
        "--set",
        "geometry.views=-2",
    ]);
    assert!(
        !ok && t.contains("tiny.yaml") && t.contains("geometry.views"),
        "{t}"
    );
    assert!(
        t.contains("--set geometry.views=-2") && !bad.exists(),
        "{t}"
    );
    let (ok, t) = prism(&[
        "simulate",
        &cfg,
        "-o",
        bad.to_str().unwrap(),
        "--set",
        "views",
    ]);
    assert!(!ok && t.contains("key.path=value"), "{t}");
}

/// Sizes whose arrays could not exist, or would not fit in the memory available, are refused
/// before anything is allocated, naming the field; `--dry-run` itemises the estimate. A scene
/// file edited to such a size is refused by `info` and `recon` alike.
#[test]
fn sizes_are_checked_before_anything_is_allocated() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene");
    let out_s = out.to_str().unwrap();
    let cfg = write(dir.path(), "ok.yaml", &tiny());
    let (ok, t) = prism(&["simulate", &cfg, "-o", out_s, "--dry-run"]);
    assert!(ok, "{t}");
    for needle in [
        "estimated peak",
        "projections (2 channels × 7 views × 24×32",
    ] {
        assert!(t.contains(needle), "`{needle}` not in:\n{t}");
    }
    assert!(!out.exists(), "a dry run writes nothing");
    let cases = [
        // 10⁵ cubed: 10¹⁵ voxels (the process used to abort on a 2.8·10¹⁶-byte allocation).
        (tiny().replace("n: 16", "n: 100000"), "geometry.volume.n"),
        // 2²² cubed overflows 64 bits.
        (tiny().replace("n: 16", "n: 4194304"), "geometry.volume.n"),
        // 10¹² views (memory used to grow until the process was killed).
        (
            tiny().replace("views: 5", "views: 1000000000000"),
            "geometry.views",
        ),
        // Countable but far beyond any machine: 10⁵ × 10⁵ pixels, 3000³ voxels.
        (
            tiny().replace("rows: 24, cols: 32", "rows: 100000, cols: 100000"),
            "--allow-memory",
        ),
        (tiny().replace("n: 16", "n: 3000"), "--allow-memory"),
    ];
    for (body, needle) in cases {
        let bad = write(dir.path(), "big.yaml", &body);
        let (ok, t) = prism(&["simulate", &bad, "-o", out_s]);
        assert!(!ok, "expected a refusal naming {needle}");
        assert!(t.contains(needle) && t.contains("big.yaml"), "{t}");
        assert!(!out.exists(), "nothing may be written on refusal");
    }
    // A simulated scene whose file is edited to a 2²²-cubed grid.
    let (ok, t) = prism(&["simulate", &cfg, "-o", out_s]);
    assert!(ok, "{t}");
    let yaml = std::fs::read_to_string(out.join("scene.yaml")).unwrap();
    let edited = ["nx", "ny", "nz"].iter().fold(yaml.clone(), |y, a| {
        y.replace(&format!("{a}: 16\n"), &format!("{a}: 4194304\n"))
    });
    assert_ne!(
        edited, yaml,
        "the grid's counts are not where the test expects them"
    );
    std::fs::write(out.join("scene.yaml"), edited).unwrap();
    let (ok, t) = prism(&["info", out_s]);
    assert!(!ok && t.contains("volume.n") && t.contains("2^40"), "{t}");
    let run = dir.path().join("run");
    let fdk = write(dir.path(), "fdk.yaml", "method: fdk\n");
    let (ok, t) = prism(&["recon", &fdk, "-s", out_s, "-o", run.to_str().unwrap()]);
    assert!(!ok && t.contains("2^40"), "{t}");
}
