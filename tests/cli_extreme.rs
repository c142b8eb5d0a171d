//! Stiff and extreme scenes end to end: each is simulated, then reconstructed by SART,
//! R²-Gaussian and 4D-SG through the `prism` binary; every run finishes with finite scores
//! (a NaN or infinite voxel makes the PSNR non-finite) or is refused with an error naming the
//! field. The cases:
//!
//! | case | what is extreme |
//! |---|---|
//! | `two-views` | 2 training views (~100× undersampled) |
//! | `sixteen-channels` | 16 monoenergetic channels, 40–115 keV |
//! | `zero-photons` | 3 photons per unattenuated pixel: most rays through the body count 0 |
//! | `iodine-k-edge` | channels at 30 and 36 keV, the iodine K-edge (33.2 keV) between them |
//! | `metal-insert` | iron and titanium rods (⌀ 10 mm): line integrals up to 33 at 40 keV, photon starvation at i0 = 10⁵ |
//! | `tiny-mm` | a 25 µm volume seen by a 50 µm detector (all lengths × 10⁻⁴) |
//! | `huge-mm` | a 2.56 km volume (all lengths × 10⁴) |
//! | `one-channel-left` | at half the views every channel but the first is missing |
//! | `source-inside` | the source inside the volume: refused (`geometry.dso`) |

mod common;

use common::{path, phantom_config, prism};

/// Simulate `config` (YAML) and run SART, R²-Gaussian and 4D-SG on it (short budgets); the
/// failures, each as `method: message`.
fn run_all(dir: &std::path::Path, name: &str, config: &str) -> Vec<String> {
    let cfg = dir.join(format!("{name}.yaml"));
    std::fs::write(&cfg, config).unwrap();
    let scene = dir.join(name);
    let (ok, t) = prism(&["simulate", path(&cfg), "-o", path(&scene)]);
    if !ok {
        return vec![format!("simulate: {t}")];
    }
    let mut failures = Vec::new();
    for (method, settings) in [
        ("sart", "iterations: 2\n"),
        (
            "r2gs",
            "iterations: 40\ninit: { n_points: 400 }\neval_every: 0\n",
        ),
        (
            "4dsg",
            "iterations: 40\ninit: { n_points: 400 }\neval_every: 0\n\
             stage2: { iterations: 20, curve_model: { width: 8, depth: 1 } }\n",
        ),
    ] {
        let rc = dir.join(format!("{name}-{method}.yaml"));
        std::fs::write(&rc, format!("method: {method}\n{settings}")).unwrap();
        let out = dir.join(format!("{name}-{method}"));
        let (ok, t) = prism(&["recon", path(&rc), "-s", path(&scene), "-o", path(&out)]);
        if !ok {
            failures.push(format!("{method}: {t}"));
            continue;
        }
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap())
                .unwrap();
        for c in m["channels"].as_array().unwrap() {
            for key in ["psnr", "ssim"] {
                let v = c[key].as_f64();
                assert!(
                    v.is_some_and(f64::is_finite),
                    "{name}, {method}, {}: {key} {:?} (a non-finite volume)",
                    c["label"],
                    c[key]
                );
            }
        }
    }
    failures
}

/// The built-in phantom config with its lengths scaled by `s` and `extra` appended.
fn scaled(name: &str, views: usize, kevs: &[u32], s: f64, extra: &str) -> String {
    let base = phantom_config(name, views, 24, 32, kevs);
    let scale = |text: String, key: &str, v: f64| text.replace(key, &format!("{}", v * s));
    let mut t = base;
    for (key, v) in [
        ("1000.0", 1000.0),
        ("1500.0", 1500.0),
        ("512.0", 512.0),
        ("256.0", 256.0),
        ("110.0", 110.0),
    ] {
        t = scale(t, key, v);
    }
    format!("{t}{extra}")
}

#[test]
fn stiff_and_extreme_scenes_finish_finite_or_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let missing: String = (0..24)
        .step_by(2)
        .flat_map(|v| (1..3).map(move |c| format!("[{v}, {c}], ")))
        .collect();
    let sixteen: Vec<u32> = (0..16).map(|i| 40 + 5 * i).collect();
    let cases: Vec<(&str, String)> = vec![
        ("two-views", scaled("two-views", 2, &[40, 70], 1.0, "")),
        (
            "sixteen-channels",
            scaled("sixteen-channels", 24, &sixteen, 1.0, ""),
        ),
        (
            "zero-photons",
            scaled("zero-photons", 24, &[40, 70], 1.0, "noise: { i0: 3.0 }\n"),
        ),
        (
            "iodine-k-edge",
            scaled("iodine-k-edge", 24, &[30, 36], 1.0, ""),
        ),
        (
            "metal-insert",
            phantom_config("metal-insert", 24, 24, 32, &[40, 70]).replace(
                "phantom: { radius_mm: 110.0 }",
                "phantom:\n    radius_mm: 110.0\n    inserts:\n      \
                 - { label: iron rod, ellipsoid: { centre: [35, -40, 0], semi_axes: [5, 5, 40] }, \
                 materials: [[water, -1.0], [iron, 1.0]] }\n      \
                 - { label: titanium rod, ellipsoid: { centre: [-25, -45, 0], semi_axes: [5, 5, 40] }, \
                 materials: [[water, -1.0], [titanium, 1.0]] }\nnoise: { i0: 100000.0 }",
            ),
        ),
        ("tiny-mm", scaled("tiny-mm", 24, &[40, 70], 1e-4, "")),
        ("huge-mm", scaled("huge-mm", 24, &[40, 70], 1e4, "")),
        (
            "one-channel-left",
            scaled(
                "one-channel-left",
                24,
                &[40, 55, 70],
                1.0,
                &format!("missing: [{missing}]\n"),
            ),
        ),
    ];
    for (name, config) in &cases {
        let failures = run_all(dir.path(), name, config);
        assert!(failures.is_empty(), "{name}: {failures:#?}");
    }

    // The source inside the volume: refused before anything is simulated, naming the field.
    let inside = phantom_config("source-inside", 24, 24, 32, &[40, 70]).replace("1000.0", "100.0");
    let failures = run_all(dir.path(), "source-inside", &inside);
    assert!(
        failures.len() == 1 && failures[0].starts_with("simulate") && failures[0].contains("dso"),
        "{failures:#?}"
    );
}
