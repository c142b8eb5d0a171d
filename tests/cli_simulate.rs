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
