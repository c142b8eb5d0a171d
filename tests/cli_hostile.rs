//! Hostile and malformed inputs against the `prism` binary, one test per cause of failure found
//! by the reliability sweep (#39); each failed before its fix (an abort, a panic, a silent wrong
//! result or a lost file) and must now end in a clean error naming the file and the field, or
//! leave every user file in place:
//!
//! | class | cause | test |
//! |---|---|---|
//! | allocation before validation | a model's stored geometry | `a_model_with_a_huge_stored_geometry_is_refused` |
//! | | `.npy` headers of `hu:` volumes and run volumes | `npy_headers_declaring_more_than_the_file_are_refused` |
//! | | `angles.count` of 10¹² (also in `--dry-run`) | `an_import_of_a_trillion_views_is_refused_even_dry` |
//! | | TIFF pages checked only after all are decoded | `a_tiff_page_of_another_size_is_refused_before_decoding` |
//! | | the evaluation grid outside the estimate and the suite's checks | `the_evaluation_grid_is_estimated_and_checked` |
//! | | `--allow-memory` ending in an abort | `an_allocation_the_system_cannot_give_ends_cleanly` |
//! | crash on malformed state | a stage-1 checkpoint's view beyond the scene | `a_geometry_checkpoint_naming_a_foreign_view_is_refused` |
//! | | a `--set` key of 50 000 segments (a stack overflow) | `a_set_key_nested_beyond_any_config_is_refused` |
//! | silent wrong result | an import channel listing a view twice | `an_import_channel_listing_a_view_twice_is_refused` |
//! | | a basis run without `basis.safetensors` queried at an energy | `a_basis_run_missing_its_materials_refuses_an_energy_query` |
//! | | a resume file beyond the run's end | `a_resume_file_beyond_the_runs_end_is_refused` (every field: `prism_recon`'s `resume_fields_out_of_range_are_refused`) |
//! | | `report` columns by method only | `report_columns_tell_runs_of_one_method_apart` |
//! | | a scoring error after the reconstruction | `an_evaluation_that_cannot_run_fails_before_reconstructing` |
//! | crash on the machine | a Vulkan driver that does not load, with `--device wgpu` | `a_gpu_without_a_loadable_driver_is_an_error_not_a_panic` |
//! | data loss | (`tests/cli_outputs.rs`) | |

mod common;

use common::{STAGE2, npy_with_header, path, prism, run_4dsg, simulated, with_fdk};
use prism_domain::testing::edit_metadata;
use std::path::{Path, PathBuf};

#[test]
fn a_model_with_a_huge_stored_geometry_is_refused() {
    let (dir, _, run) = run_4dsg(STAGE2);
    let model = run.join("gaussians.safetensors");
    // 10⁵ voxels per axis: more than one array can hold.
    edit_metadata(&model, &model, "info", |v| {
        for k in ["nx", "ny", "nz"] {
            v["geometry"]["volume"][k] = 100_000.into();
        }
    });
    let out = dir.path().join("q.npy");
    let (ok, t) = prism(&["query", path(&run), "--tau", "0.5", "-o", path(&out)]);
    assert!(
        !ok && t.contains("gaussians.safetensors") && t.contains("metadata.info.geometry"),
        "{t}"
    );
    // 9000³ voxels of 10 µm: a valid grid, 2.9 TB: the query's estimate refuses it, and with
    // --allow-memory the allocation the system cannot give ends in a clean error.
    edit_metadata(&model, &model, "info", |v| {
        for (k, d) in [("nx", "dx"), ("ny", "dy"), ("nz", "dz")] {
            v["geometry"]["volume"][k] = 9000.into();
            v["geometry"]["volume"][d] = 0.01.into();
        }
    });
    let (ok, t) = prism(&["query", path(&run), "--tau", "0.5", "-o", path(&out)]);
    assert!(!ok && t.contains("--allow-memory"), "{t}");
    let (ok, t) = prism(&[
        "query",
        path(&run),
        "--tau",
        "0.5",
        "-o",
        path(&out),
        "--dry-run",
    ]);
    assert!(ok && t.contains("estimated peak"), "{t}");
    let (ok, t) = prism(&[
        "query",
        path(&run),
        "--tau",
        "0.5",
        "-o",
        path(&out),
        "--allow-memory",
    ]);
    assert!(!ok && t.contains("error: out of memory"), "{t}");
    assert!(!out.exists());
}

#[test]
fn npy_headers_declaring_more_than_the_file_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    // A `hu:` volume of a scene config.
    let hu = dir.path().join("hu.npy");
    npy_with_header(&hu, "<i2", "(100000, 100000, 100000)", &[0; 64]);
    let cfg = dir.path().join("hu.yaml");
    std::fs::write(
        &cfg,
        "name: hu\ngeometry:\n  beam: cone\n  dso: 1000.0\n  dsd: 1500.0\n  \
         detector: { rows: 12, cols: 12, size_mm: [512.0, 512.0] }\n  \
         volume: { n: 12, size_mm: 256.0 }\n  views: 8\n  test_views: 2\n\
         object:\n  hu: { path: hu.npy, voxel_mm: [1.0, 1.0, 1.0] }\n\
         channels:\n  - { kind: mono, kev: 40 }\n",
    )
    .unwrap();
    let (ok, t) = prism(&["simulate", path(&cfg), "-o", path(&dir.path().join("s"))]);
    assert!(!ok && t.contains("hu.npy") && t.contains("header"), "{t}");

    // A run's channel volume read by decompose.
    let (_d, scene, fdk) = with_fdk("npy", &[40, 70]);
    let run = dir.path().join("run");
    let (ok, t) = prism(&["recon", path(&fdk), "-s", path(&scene), "-o", path(&run)]);
    assert!(ok, "{t}");
    npy_with_header(
        &run.join("40keV.npy"),
        "<f4",
        "(100000, 100000, 100000)",
        &[0; 64],
    );
    let out = dir.path().join("dec");
    let (ok, t) = prism(&[
        "decompose",
        path(&run),
        "-s",
        path(&scene),
        "-o",
        path(&out),
        "--basis",
        "water,cortical_bone",
    ]);
    assert!(
        !ok && t.contains("40keV.npy") && t.contains("header"),
        "{t}"
    );
    assert!(!out.exists());
}

/// A tiny import of line integrals (`views` × 12 × 12, zeros) with `extra` YAML lines; the
/// config's path.
fn import_config(dir: &Path, views: usize, angles: &str, channel: &str) -> PathBuf {
    let data: Vec<u8> = vec![0; views * 12 * 12 * 4];
    npy_with_header(
        &dir.join("p.npy"),
        "<f4",
        &format!("({views}, 12, 12)"),
        &data,
    );
    let cfg = dir.join("import.yaml");
    std::fs::write(
        &cfg,
        format!(
            "name: imported\ngeometry: {{prism: {{beam: cone, dso: 1000.0, dsd: 1500.0, detector: {{rows: 12, cols: 12, \
             pitch_u: 1.0, pitch_v: 1.0, offset_u: 0.0, offset_v: 0.0}}, volume: {{nx: 12, ny: 12, \
             nz: 12, dx: 1.0, dy: 1.0, dz: 1.0, offset: [0.0, 0.0, 0.0]}}}}}}\nangles: {angles}\n\
             channels:\n  - {{label: a, coordinate: {{kind: energy, kev: 60.0}}, \
             line_integrals: {{path: p.npy}}{channel}}}\nselect: {{reference: none}}\n"
        ),
    )
    .unwrap();
    cfg
}

#[test]
fn an_import_of_a_trillion_views_is_refused_even_dry() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = import_config(dir.path(), 4, "{count: 1000000000000}", "");
    let out = dir.path().join("s");
    for dry in [true, false] {
        let mut args = vec!["import", path(&cfg), "-o", path(&out)];
        if dry {
            args.push("--dry-run");
        }
        let (ok, t) = prism(&args);
        assert!(
            !ok && t.contains("angles.count") && t.contains("import.yaml"),
            "{t}"
        );
    }
    assert!(!out.exists());
}

#[test]
fn an_import_channel_listing_a_view_twice_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = import_config(dir.path(), 2, "{count: 4}", ", views: [1, 1]");
    let out = dir.path().join("s");
    let (ok, t) = prism(&["import", path(&cfg), "-o", path(&out)]);
    assert!(
        !ok && t.contains("channels[0].views[1]") && t.contains("twice"),
        "{t}"
    );
    assert!(!out.exists());
}

/// A one-page 8-bit PackBits TIFF of `width` × `height` zeros (128-byte runs: 2 bytes each).
fn packbits_tiff(path: &Path, width: u32, height: u32) {
    let runs = (width as usize).div_ceil(128);
    let mut row = Vec::new();
    let mut left = width as usize;
    for _ in 0..runs {
        let n = left.min(128);
        row.extend([(1i16 - n as i16) as u8, 0]);
        left -= n;
    }
    let strip: Vec<u8> = row.repeat(height as usize);
    let entries: [(u16, u16, u32); 8] = [
        (256, 4, width),              // ImageWidth
        (257, 4, height),             // ImageLength
        (258, 3, 8),                  // BitsPerSample
        (259, 3, 32773),              // Compression: PackBits
        (262, 3, 1),                  // Photometric: black is zero
        (273, 4, 0),                  // StripOffsets (set below)
        (278, 4, height),             // RowsPerStrip
        (279, 4, strip.len() as u32), // StripByteCounts
    ];
    let ifd_at = 8u32;
    let data_at = ifd_at + 2 + 12 * entries.len() as u32 + 4;
    let mut out = b"II*\0".to_vec();
    out.extend(ifd_at.to_le_bytes());
    out.extend((entries.len() as u16).to_le_bytes());
    for (tag, kind, value) in entries {
        let value = if tag == 273 { data_at } else { value };
        out.extend(tag.to_le_bytes());
        out.extend(kind.to_le_bytes());
        out.extend(1u32.to_le_bytes());
        if kind == 3 {
            out.extend((value as u16).to_le_bytes());
            out.extend([0, 0]);
        } else {
            out.extend(value.to_le_bytes());
        }
    }
    out.extend(0u32.to_le_bytes());
    out.extend(strip);
    std::fs::write(path, out).unwrap();
}

#[test]
fn a_tiff_page_of_another_size_is_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = import_config(dir.path(), 4, "{count: 4}", "");
    // 16 000 × 16 000 pixels (256 MB as f32) in a 4 MB file; the detector is 12 × 12.
    packbits_tiff(&dir.path().join("big.tif"), 16_000, 16_000);
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("select:", "flat: {path: big.tif}\nselect:")
        .replace("line_integrals: {path: p.npy}", "counts: {path: p.npy}");
    std::fs::write(&cfg, text).unwrap();
    let (ok, t) = prism(&["import", path(&cfg), "-o", path(&dir.path().join("s"))]);
    assert!(
        !ok && t.contains("big.tif") && t.contains("page 0") && t.contains("the detector is 12×12"),
        "{t}"
    );
}

#[test]
fn the_evaluation_grid_is_estimated_and_checked() {
    let (dir, scene, fdk) = with_fdk("grid", &[40]);
    let out = dir.path().join("run");
    let recon = |extra: &[&str]| {
        let mut args = vec!["recon", path(&fdk), "-s", path(&scene), "-o", path(&out)];
        args.extend(extra);
        prism(&args)
    };
    let (ok, t) = recon(&["--eval-grid", "4096", "--dry-run"]);
    assert!(ok && t.contains("scoring one channel on 4096³"), "{t}");
    let (ok, t) = recon(&["--eval-grid", "4096"]);
    assert!(!ok && t.contains("--allow-memory"), "{t}");
    assert!(!out.exists());
    // A suite's grid is checked when the suite loads.
    let suite = dir.path().join("suite.yaml");
    std::fs::write(
        &suite,
        format!(
            "name: s\nscenes: {{ a: {{ config: {} }} }}\nmethods: {{ fdk: {{ config: {} }} }}\n\
             evaluation: {{ grid: 100000 }}\nstudies:\n  - {{ name: t, kind: table, methods: [fdk], scenes: [a] }}\n",
            path(&dir.path().join("scene.yaml")),
            path(&fdk)
        ),
    )
    .unwrap();
    let results = dir.path().join("results");
    let (ok, t) = prism(&[
        "experiment",
        path(&suite),
        "-o",
        path(&results),
        "--dry-run",
    ]);
    assert!(!ok && t.contains("evaluation.grid"), "{t}");
}

#[test]
fn an_evaluation_that_cannot_run_fails_before_reconstructing() {
    let (dir, scene, fdk) = with_fdk("eval", &[40]);
    let out = dir.path().join("run");
    // A 2³ grid holds no 11 × 11 SSIM window: refused before FDK starts, not after.
    let (ok, t) = prism(&[
        "recon",
        path(&fdk),
        "-s",
        path(&scene),
        "-o",
        path(&out),
        "--eval-grid",
        "2",
    ]);
    assert!(
        !ok && t.contains("11×11 window") && !t.contains("fdk 40keV"),
        "{t}"
    );
}

#[test]
fn an_allocation_the_system_cannot_give_ends_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("scene.yaml");
    std::fs::write(&cfg, common::phantom_config("oom", 8, 8000, 12, &[40])).unwrap();
    let out = dir.path().join("s");
    let (ok, t) = prism(&["simulate", path(&cfg), "-o", path(&out)]);
    assert!(!ok && t.contains("--allow-memory"), "{t}");
    // Overridden: a 2 TB volume the system cannot give, a clean error (no abort, no kill).
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(["simulate", path(&cfg), "-o", path(&out), "--allow-memory"])
        .output()
        .unwrap();
    let t = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{t}");
    assert!(t.contains("error: out of memory"), "{t}");
    assert!(!out.exists());
}

#[test]
fn a_set_key_nested_beyond_any_config_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("scene.yaml");
    std::fs::write(&cfg, common::phantom_config("deep", 8, 12, 12, &[40])).unwrap();
    let key = format!("{}=1", vec!["a"; 50_000].join("."));
    let (ok, t) = prism(&[
        "simulate",
        path(&cfg),
        "-o",
        path(&dir.path().join("s")),
        "--set",
        &key,
    ]);
    assert!(
        !ok && t.contains("--set") && t.contains("50000 segments"),
        "{t}"
    );
    assert!(
        t.len() < 2000,
        "the error quotes the key in full: {} bytes",
        t.len()
    );
}

#[test]
fn a_geometry_checkpoint_naming_a_foreign_view_is_refused() {
    let (dir, scene, run) = run_4dsg(STAGE2);
    let ckpt = run.join("geometry.safetensors");
    let cfg = dir.path().join("4dsg.yaml");
    for (views, why) in [(vec![0, 99], "view 99"), (vec![0, 0], "twice")] {
        edit_metadata(
            &ckpt,
            &dir.path().join("geometry.safetensors"),
            "views",
            |v| *v = serde_json::json!(views),
        );
        let (ok, t) = prism(&[
            "recon",
            path(&cfg),
            "-s",
            path(&scene),
            "-o",
            path(&dir.path().join("again")),
            "--from-geometry",
            path(&dir.path().join("geometry.safetensors")),
        ]);
        assert!(
            !ok && t.contains("metadata.views") && t.contains(why),
            "{t}"
        );
    }
}

#[test]
fn a_basis_run_missing_its_materials_refuses_an_energy_query() {
    let (dir, _, run) = run_4dsg(
        "stage2: { iterations: 10, basis: { materials: [water, cortical_bone] }, \
         freeze: { position: false, rotation: false, scale: false, density: false } }\n",
    );
    let out = dir.path().join("vmi.npy");
    let (ok, t) = prism(&["query", path(&run), "--kev", "60", "-o", path(&out)]);
    assert!(ok && t.contains("from the basis"), "{t}");
    std::fs::remove_file(run.join("basis.safetensors")).unwrap();
    let (ok, t) = prism(&[
        "query",
        path(&run),
        "--kev",
        "60",
        "-o",
        path(&out),
        "--force",
    ]);
    assert!(
        !ok && t.contains("basis.safetensors") && t.contains("basis head"),
        "{t}"
    );
}

#[test]
fn report_columns_tell_runs_of_one_method_apart() {
    let (dir, scene) = simulated("report", 8, 12, 12, &[40]);
    let mut runs = Vec::new();
    for (name, filter) in [("fdk-hann", "hann"), ("fdk-ramp", "ram_lak")] {
        let cfg = dir.path().join(format!("{name}.yaml"));
        std::fs::write(&cfg, format!("method: fdk\nfilter: {filter}\n")).unwrap();
        let out = dir.path().join(name);
        let (ok, t) = prism(&["recon", path(&cfg), "-s", path(&scene), "-o", path(&out)]);
        assert!(ok, "{t}");
        runs.push(out);
    }
    let (ok, t) = prism(&["report", path(&runs[0]), path(&runs[1])]);
    assert!(
        ok && t.contains("fdk (fdk-hann) PSNR") && t.contains("fdk (fdk-ramp) PSNR"),
        "{t}"
    );
}

#[test]
fn a_resume_file_beyond_the_runs_end_is_refused() {
    // A long run interrupted (SIGINT, once its first periodic checkpoint shows the handler is
    // in place) saves its state; that file with its iteration counter past the end used to be
    // accepted, and the run published as finished.
    let (dir, scene) = simulated("resume", 8, 12, 12, &[40]);
    let cfg = dir.path().join("r2gs.yaml");
    std::fs::write(
        &cfg,
        "method: r2gs\niterations: 1000000\ninit: { n_points: 200 }\neval_every: 0\n\
         densify: null\ncheckpoint_every: 20\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let ckpt = dir.path().join("run.ckpt");
    let args = |resume: bool| {
        let mut a = vec![
            "recon",
            path(&cfg),
            "-s",
            path(&scene),
            "-o",
            path(&out),
            "--checkpoint",
            path(&ckpt),
        ];
        if resume {
            a.push("--resume");
        }
        a
    };
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(args(false))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while !ckpt.is_file() {
        assert!(start.elapsed().as_secs() < 120, "no checkpoint written");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let killed = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    assert!(!status.success() && ckpt.is_file() && !out.exists());
    edit_metadata(&ckpt, &ckpt, "current", |v| {
        v["progress"]["iteration"] = 100_000_000.into()
    });
    let (ok, t) = prism(&args(true));
    assert!(
        !ok && t.contains("run.ckpt") && t.contains("metadata.current.progress.iteration"),
        "{t}"
    );
    assert!(!out.exists(), "nothing published");
}

/// A wgpu build on a machine whose Vulkan loader finds no driver (seen on a GPU machine lacking
/// glvnd, which the NVIDIA ICD links against): the runtime panicked on its own thread and then the
/// main one. Now the device is probed once and the run ends in an error naming the cause and the
/// way out. The Vulkan loader and glvnd's EGL (wgpu's fallback) are pointed at a driver file that
/// does not exist, so no adapter comes up.
#[cfg(feature = "wgpu")]
#[test]
fn a_gpu_without_a_loadable_driver_is_an_error_not_a_panic() {
    let (dir, scene) = simulated("no-driver", 8, 12, 16, &[50]);
    let rc = dir.path().join("r2gs.yaml");
    std::fs::write(&rc, "method: r2gs\niterations: 2\ninit: { n_points: 50 }\n").unwrap();
    let missing = dir.path().join("no-such-icd.json");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(["recon", path(&rc), "-s", path(&scene), "-o"])
        .arg(dir.path().join("run"))
        .args(["--device", "wgpu"])
        .env("VK_DRIVER_FILES", &missing)
        .env("VK_ICD_FILENAMES", &missing)
        .env("__EGL_VENDOR_LIBRARY_FILENAMES", &missing)
        .output()
        .expect("prism runs");
    let t = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{t}");
    assert!(
        t.contains("no usable GPU adapter") && t.contains("--device cpu"),
        "{t}"
    );
    assert!(!t.contains("panicked"), "{t}");
}
