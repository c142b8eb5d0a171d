//! Shared helpers of the end-to-end tests (each test binary uses a part of them).
#![allow(dead_code)]

use std::process::Command;

/// Run the `prism` binary; returns whether it succeeded and its stdout + stderr.
pub fn prism(args: &[&str]) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(args)
        .output()
        .expect("prism runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o.status.success(), text)
}

/// A scene config of the built-in phantom (radius 110 mm, cone beam, DSO 1000 mm, DSD 1500 mm,
/// a 512 mm detector) with `views` training and 2 test views, an `n`³ grid of 256 mm and a
/// `det`² detector, one monoenergetic channel per entry of `kevs`.
pub fn phantom_config(name: &str, views: usize, n: usize, det: usize, kevs: &[u32]) -> String {
    let channels: String = kevs
        .iter()
        .map(|k| format!("  - {{ kind: mono, kev: {k} }}\n"))
        .collect();
    format!(
        "name: {name}\ngeometry:\n  beam: cone\n  dso: 1000.0\n  dsd: 1500.0\n  \
         detector: {{ rows: {det}, cols: {det}, size_mm: [512.0, 512.0] }}\n  \
         volume: {{ n: {n}, size_mm: 256.0 }}\n  views: {views}\n  test_views: 2\n\
         object:\n  phantom: {{ radius_mm: 110.0 }}\nchannels:\n{channels}"
    )
}

/// `path` as `&str` (the tests' paths are UTF-8).
pub fn path(p: &std::path::Path) -> &str {
    p.to_str().unwrap()
}

/// Simulate [`phantom_config`] into `<dir>/scene` of a new temporary directory.
pub fn simulated(
    name: &str,
    views: usize,
    n: usize,
    det: usize,
    kevs: &[u32],
) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("scene.yaml");
    std::fs::write(&cfg, phantom_config(name, views, n, det, kevs)).unwrap();
    let scene = dir.path().join("scene");
    let (ok, t) = prism(&["simulate", path(&cfg), "-o", path(&scene)]);
    assert!(ok, "{t}");
    (dir, scene)
}
