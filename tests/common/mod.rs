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

pub use prism_domain::testing::phantom_config_yaml as phantom_config;

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

/// A `.npy` (version 1) whose header declares `descr` and `shape` (Python tuple syntax),
/// followed by `data` bytes: written by hand, an independent writer that can also lie.
pub fn npy_with_header(path: &std::path::Path, descr: &str, shape: &str, data: &[u8]) {
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while !(10 + dict.len() + 1).is_multiple_of(64) {
        dict.push(' ');
    }
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((dict.len() as u16).to_le_bytes());
    out.extend(dict.as_bytes());
    out.extend(data);
    std::fs::write(path, out).unwrap();
}

/// A tiny 4D-SG run of a two-channel scene (`extra` appended to its config): (tempdir, scene,
/// run directory).
pub fn run_4dsg(extra: &str) -> (tempfile::TempDir, std::path::PathBuf, std::path::PathBuf) {
    let (dir, scene) = simulated("hostile", 8, 12, 12, &[40, 70]);
    let cfg = dir.path().join("4dsg.yaml");
    std::fs::write(
        &cfg,
        format!("method: 4dsg\niterations: 30\ninit: {{ n_points: 200 }}\neval_every: 0\n{extra}"),
    )
    .unwrap();
    let out = dir.path().join("run");
    let (ok, t) = prism(&["recon", path(&cfg), "-s", path(&scene), "-o", path(&out)]);
    assert!(ok, "{t}");
    (dir, scene, out)
}

/// A simulated scene (8 views, 12³, at `kevs`) and an FDK config beside it: (tempdir, scene,
/// config).
pub fn with_fdk(
    name: &str,
    kevs: &[u32],
) -> (tempfile::TempDir, std::path::PathBuf, std::path::PathBuf) {
    let (dir, scene) = simulated(name, 8, 12, 12, kevs);
    let fdk = dir.path().join("fdk.yaml");
    std::fs::write(&fdk, "method: fdk\n").unwrap();
    (dir, scene, fdk)
}

pub const STAGE2: &str = "stage2: { iterations: 10, curve_model: { width: 8, depth: 1 } }\n";
