//! End-to-end: the `prism` binary simulates a small scene, inspects it, and refuses bad input
//! with an error that names the file and the field, leaving nothing half-written.

mod common;

use common::prism;
use std::path::Path;

const TINY: &str = r#"
name: tiny-cli
seed: 1
geometry:
  beam: cone
  dso: 1000.0
  dsd: 1500.0
  detector: { rows: 24, cols: 32, size_mm: [512.0, 384.0] }
  volume: { n: 16, size_mm: 256.0 }
  views: 5
  test_views: 2
object:
  phantom: { radius_mm: 110.0 }
channels:
  - { kind: mono, kev: 40 }
  - { kind: mono, kev: 100 }
"#;

fn write(dir: &Path, name: &str, body: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, body).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn simulate_then_info() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(dir.path(), "tiny.yaml", TINY);
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
        (TINY.replace("dso: 1000.0", "dso: -1000.0"), "geometry.dso"),
        (TINY.replace("kev: 100", "kev: 400"), "channels[1].kev"),
        (
            TINY.replace("kind: mono, kev: 40", "kind: laser, kev: 40"),
            "channels",
        ),
        (
            TINY.replace("rows: 24", "rows: 0"),
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
