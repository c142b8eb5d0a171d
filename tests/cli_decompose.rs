//! `prism decompose`: basis fractions and VMIs from a run's volumes, scored against the
//! decomposition of the scene's references; refusals name the cause.

mod common;

use common::{path, prism, simulated};
use ndarray::{Array3, Axis};
use prism_domain::scene::Scene;

#[test]
fn a_runs_volumes_decompose_into_basis_fractions_and_vmis() {
    let (dir, scene_dir) = simulated("dec", 8, 16, 16, &[40, 55, 70, 100]);
    let scene = Scene::load(&scene_dir).unwrap();
    // A "run" holding the references themselves decomposes exactly like them.
    let run = dir.path().join("run");
    std::fs::create_dir(&run).unwrap();
    let refs = scene.references.as_ref().unwrap();
    for (c, ch) in scene.channels.iter().enumerate() {
        let v: Array3<f32> = refs.index_axis(Axis(0), c).to_owned();
        ndarray_npy::write_npy(run.join(format!("{}.npy", ch.label)), &v).unwrap();
    }
    let out = dir.path().join("dec");
    let (ok, t) = prism(&[
        "decompose",
        path(&run),
        "-s",
        path(&scene_dir),
        "-o",
        path(&out),
        "--kev",
        "55,85,130",
    ]);
    assert!(ok, "{t}");
    assert!(
        t.contains("130 keV lies outside the channels' energies"),
        "{t}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("decomposition.json")).unwrap())
            .unwrap();
    assert_eq!(
        report["basis"],
        serde_json::json!(["water", "cortical_bone", "iodine"])
    );
    assert_eq!(report["spectra_exact"], true);
    let scores = &report["against_references"];
    for r in scores["fraction_rmse"].as_array().unwrap() {
        assert!(r.as_f64().unwrap() < 1e-6, "{report}");
    }
    // The VMI at the observed 55 keV is the 55 keV reference up to the basis model's residual:
    // the phantom's adipose, soft tissue, calcium and air are not exact mixtures of water, bone
    // and iodine across 40–100 keV (largest gap measured: 0.26 % of the peak).
    let vmi: Array3<f32> = ndarray_npy::read_npy(out.join("vmi-55keV.npy")).unwrap();
    let r55 = refs.index_axis(Axis(0), 1);
    let peak = r55.iter().fold(0.0f32, |a, &v| a.max(v));
    let worst = vmi
        .iter()
        .zip(r55.iter())
        .fold(0.0f32, |w, (a, b)| w.max((a - b).abs()));
    assert!(worst < 5e-3 * peak, "worst {worst} of peak {peak}");
    let extrapolated: Vec<bool> = report["vmi"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["extrapolated"].as_bool().unwrap())
        .collect();
    assert_eq!(extrapolated, vec![false, false, true]);
    for name in [
        "water.npy",
        "cortical_bone.npy",
        "iodine.npy",
        "vmi-85keV.npy",
    ] {
        assert!(out.join(name).is_file(), "{name}");
    }

    // A volume off the scene's grid is refused, naming its file.
    let bad = dir.path().join("bad-run");
    std::fs::create_dir(&bad).unwrap();
    for ch in &scene.channels {
        ndarray_npy::write_npy(
            bad.join(format!("{}.npy", ch.label)),
            &Array3::<f32>::zeros((2, 2, 2)),
        )
        .unwrap();
    }
    let z = dir.path().join("z");
    let (ok, t) = prism(&[
        "decompose",
        path(&bad),
        "-s",
        path(&scene_dir),
        "-o",
        path(&z),
    ]);
    assert!(
        !ok && t.contains("40keV.npy") && t.contains("the scene's grid"),
        "{t}"
    );
    assert!(!z.exists(), "nothing is written on refusal");

    // A non-empty output directory and an underdetermined basis are refused.
    let (ok, t) = prism(&[
        "decompose",
        path(&run),
        "-s",
        path(&scene_dir),
        "-o",
        path(&out),
    ]);
    assert!(!ok && t.contains("not empty"), "{t}");
    let five = "water,cortical_bone,iodine,calcium,adipose";
    let (ok, t) = prism(&[
        "decompose",
        path(&run),
        "-s",
        path(&scene_dir),
        "-o",
        path(&dir.path().join("x")),
        "--basis",
        five,
    ]);
    assert!(!ok && t.contains("1 to 4 materials"), "{t}");
    let (ok, t) = prism(&[
        "decompose",
        path(&run),
        "-s",
        path(&scene_dir),
        "-o",
        path(&dir.path().join("y")),
        "--basis",
        "water,calcium,cortical_bone",
    ]);
    // Cortical bone attenuates nearly like calcium diluted in water across 40–100 keV.
    assert!(
        !ok && t.contains("cannot separate calcium from cortical_bone"),
        "{t}"
    );
}

/// A 4D-SG run with the basis head carries its material maps: `prism decompose` voxelizes them
/// (source `gaussians`), every channel volume the run wrote is exactly its basis mixture
/// `Σ_b f_b·μ̄_cb`, and `prism query --kev` gives the same monoenergetic image as the
/// decomposition, with a warning outside the channels' energies and a refusal outside the table.
#[test]
fn a_basis_head_run_carries_its_material_maps() {
    let (dir, scene_dir) = simulated("basis", 12, 16, 16, &[40, 55, 70, 100]);
    let scene = Scene::load(&scene_dir).unwrap();
    let rc = dir.path().join("basis.yaml");
    std::fs::write(
        &rc,
        "method: 4dsg\niterations: 40\neval_every: 0\ninit: {n_points: 400}\ndensify: null\n\
         stage2: {iterations: 30, basis: {}}\n",
    )
    .unwrap();
    let run = dir.path().join("run");
    let (ok, t) = prism(&["recon", path(&rc), "-s", path(&scene_dir), "-o", path(&run)]);
    assert!(ok && run.join("basis.safetensors").is_file(), "{t}");

    let out = dir.path().join("dec");
    let (ok, t) = prism(&[
        "decompose",
        path(&run),
        "-s",
        path(&scene_dir),
        "-o",
        path(&out),
        "--kev",
        "55",
    ]);
    assert!(ok && t.contains("from the run's basis Gaussians"), "{t}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("decomposition.json")).unwrap())
            .unwrap();
    assert_eq!(report["source"], "gaussians");
    let fractions: Vec<Array3<f32>> = ["water", "cortical_bone", "iodine"]
        .iter()
        .map(|m| ndarray_npy::read_npy(out.join(format!("{m}.npy"))).unwrap())
        .collect();
    assert!(
        fractions.iter().flatten().all(|&f| f >= 0.0),
        "fractions are non-negative"
    );
    let matrix = report["matrix"].as_array().unwrap();
    for (c, ch) in scene.channels.iter().enumerate() {
        let vol: Array3<f32> =
            ndarray_npy::read_npy(run.join(format!("{}.npy", ch.label))).unwrap();
        let peak = vol.iter().fold(0.0f32, |a, &v| a.max(v));
        assert!(peak > 0.0, "{}: empty volume", ch.label);
        let row: Vec<f32> = (0..3)
            .map(|b| matrix[c][b].as_f64().unwrap() as f32)
            .collect();
        let worst = ndarray::Zip::indexed(&vol).fold(0.0f32, |w, i, &v| {
            let mix: f32 = (0..3).map(|b| row[b] * fractions[b][i]).sum();
            w.max((v - mix).abs())
        });
        // f32 voxelization of two linear functions of the same Gaussians.
        assert!(
            worst <= 1e-4 * peak,
            "{}: worst {worst} of {peak}",
            ch.label
        );
    }

    // The VMI at 55 keV, by query and by decomposition, is the 55 keV channel's volume.
    let q = dir.path().join("q55.npy");
    let (ok, t) = prism(&["query", path(&run), "--kev", "55", "-o", path(&q)]);
    assert!(ok && !t.contains("warning"), "{t}");
    let by_query: Array3<f32> = ndarray_npy::read_npy(&q).unwrap();
    let by_dec: Array3<f32> = ndarray_npy::read_npy(out.join("vmi-55keV.npy")).unwrap();
    let channel: Array3<f32> = ndarray_npy::read_npy(run.join("55keV.npy")).unwrap();
    let peak = channel.iter().fold(0.0f32, |a, &v| a.max(v));
    for other in [&by_dec, &channel] {
        let worst = by_query
            .iter()
            .zip(other.iter())
            .fold(0.0f32, |w, (a, b)| w.max((a - b).abs()));
        assert!(worst <= 1e-4 * peak, "worst {worst} of {peak}");
    }
    let (ok, t) = prism(&[
        "query",
        path(&run),
        "--kev",
        "130",
        "-o",
        path(&dir.path().join("q130.npy")),
    ]);
    assert!(
        ok && t.contains("outside the trained channels' energies"),
        "{t}"
    );
    let (ok, t) = prism(&[
        "query",
        path(&run),
        "--kev",
        "200",
        "-o",
        path(&dir.path().join("q200.npy")),
    ]);
    assert!(!ok && t.contains("kev"), "{t}");

    // The two-step path stays available on the same run.
    let img = dir.path().join("img");
    let (ok, t) = prism(&[
        "decompose",
        path(&run),
        "-s",
        path(&scene_dir),
        "-o",
        path(&img),
        "--image-domain",
    ]);
    assert!(ok && t.contains("from the channel volumes"), "{t}");

    // Frozen basis densities are refused before any training.
    let (ok, t) = prism(&[
        "recon",
        path(&rc),
        "-s",
        path(&scene_dir),
        "-o",
        path(&dir.path().join("frozen")),
        "--set",
        "stage2.freeze.density=true",
    ]);
    assert!(!ok && t.contains("stage2.freeze.density"), "{t}");
}
