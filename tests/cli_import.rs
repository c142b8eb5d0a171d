//! `prism import` round trip: counts simulated from a known scene (360 views, flat and dark
//! fields, Poisson noise) written as `.npy` (u16), a TIFF stack (the flat fields) and a raw
//! big-endian file (the dark field) → `prism import` → the scene's line integrals to the noise
//! level, 50 of the 360 views picked, a full-view FDK reference; then 4D-SG trains on it.
//! The counts are simulated: the measured scan that ships (`data/real/bird`) is line integrals.
//! A fan-beam MATLAB v7.3 sinogram with per-channel reference methods is the second test, an
//! off-centre rotation axis estimated and applied the third.

mod common;

use common::{path, phantom_config, prism};
use prism_domain::geometry::Geometry;
use prism_domain::scene::Scene;
use rand::SeedableRng;
use rand_distr::{Distribution, Poisson};
use std::path::Path;

const VIEWS: usize = 360;
const I0: f64 = 2.0e4;
const DARK: f64 = 50.0;
const FLATS: usize = 3;

/// A version-1 `.npy` of little-endian u16, written by hand (an independent writer).
fn write_npy_u16(path: &Path, shape: [usize; 3], data: &[u16]) {
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    let shape = format!("({}, {}, {})", shape[0], shape[1], shape[2]);
    common::npy_with_header(path, "<u2", &shape, &bytes);
}

#[test]
fn counts_with_flat_and_dark_fields_import_to_the_scenes_line_integrals() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("p.yaml");
    std::fs::write(&config, phantom_config("p", VIEWS, 16, 16, &[40, 70, 100])).unwrap();
    let truth_dir = dir.path().join("truth");
    let (ok, t) = prism(&["simulate", path(&config), "-o", path(&truth_dir)]);
    assert!(ok, "{t}");
    let truth = Scene::load(&truth_dir).unwrap();
    let g = &truth.geometry;
    let (rows, cols) = (g.detector.rows, g.detector.cols);
    let full = Geometry::full_turn(VIEWS);
    assert!((0..VIEWS).all(|v| (g.angles_rad[v] - full[v]).abs() < 1e-12));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut poisson = |mean: f64| Poisson::new(mean).unwrap().sample(&mut rng);
    // Counts per channel: Poisson(I0·e^(−p)) + dark (itself Poisson).
    for c in 0..truth.n_channels() {
        let mut data = Vec::with_capacity(VIEWS * rows * cols);
        for v in 0..VIEWS {
            for r in 0..rows {
                for k in 0..cols {
                    let mean = I0 * (-(truth.projections[[c, v, r, k]] as f64)).exp();
                    let n = poisson(mean) + poisson(DARK);
                    data.push(n.min(65535.0) as u16);
                }
            }
        }
        write_npy_u16(
            &dir.path().join(format!("counts{c}.npy")),
            [VIEWS, rows, cols],
            &data,
        );
    }
    // Flat fields: three noisy frames in one float TIFF; dark: one big-endian u16 raw frame.
    let flat = std::fs::File::create(dir.path().join("flat.tif")).unwrap();
    let mut tif = tiff::encoder::TiffEncoder::new(flat).unwrap();
    for _ in 0..FLATS {
        let frame: Vec<f32> = (0..rows * cols)
            .map(|_| (poisson(I0) + poisson(DARK)) as f32)
            .collect();
        tif.write_image::<tiff::encoder::colortype::Gray32Float>(cols as u32, rows as u32, &frame)
            .unwrap();
    }
    let dark: Vec<u8> = (0..rows * cols)
        .flat_map(|_| (poisson(DARK) as u16).to_be_bytes())
        .collect();
    std::fs::write(dir.path().join("dark.raw"), dark).unwrap();
    let detector = serde_json::to_string(&g.detector).unwrap();
    let volume = serde_json::to_string(&g.volume).unwrap();
    let channels: String = truth
        .channels
        .iter()
        .enumerate()
        .map(|(c, ch)| {
            format!(
                "  - {{label: {}, coordinate: {}, counts: {{path: counts{c}.npy}}}}\n",
                ch.label,
                serde_json::to_string(&ch.coordinate).unwrap()
            )
        })
        .collect();
    let import = dir.path().join("import.yaml");
    std::fs::write(
        &import,
        format!(
            "name: imported\ngeometry: {{prism: {{beam: cone, dso: {}, dsd: {}, detector: {detector}, \
             volume: {volume}}}}}\nangles: {{count: {VIEWS}}}\n\
             flat: {{path: flat.tif}}\ndark: {{path: dark.raw, raw: {{dtype: u16, shape: [{rows}, {cols}], big_endian: true}}}}\n\
             channels:\n{channels}select: {{views: 50, test_views: 20}}\n",
            g.dso, g.dsd
        ),
    )
    .unwrap();
    let out = dir.path().join("imported");
    // The estimate, itemised; nothing is written.
    let (ok, t) = prism(&["import", path(&import), "-o", path(&out), "--dry-run"]);
    assert!(
        ok && t.contains(&format!(
            "projections of the full scan (3 channels × {VIEWS} views × {rows}×{cols})"
        )) && t.contains("full-view reference of one channel")
            && t.contains("estimated peak"),
        "{t}"
    );
    assert!(!out.exists(), "a dry run writes nothing");
    // A 4096³ reference grid cannot fit: refused before any image is read, unless allowed.
    let huge = dir.path().join("huge.yaml");
    let text = std::fs::read_to_string(&import).unwrap();
    let big_volume =
        serde_json::to_string(&prism_domain::geometry::VolumeGrid::cube(4096, 0.01)).unwrap();
    std::fs::write(&huge, text.replace(&volume, &big_volume)).unwrap();
    let (ok, t) = prism(&["import", path(&huge), "-o", path(&out)]);
    assert!(
        !ok && t.contains("--allow-memory") && t.contains("huge.yaml"),
        "{t}"
    );
    assert!(!out.exists());
    let (ok, t) = prism(&["import", path(&import), "-o", path(&out)]);
    assert!(ok, "{t}");
    assert!(t.contains("50 training + 20 test views of 360"), "{t}");
    let s = Scene::load(&out).unwrap();
    assert_eq!(
        (s.n_views(), s.split.train.len(), s.split.test.len()),
        (70, 50, 20)
    );
    // Training view i is scan view ⌊i·360/50⌋, at its angle, with the truth's line integrals
    // to the noise level. Where the mean count is at least 1000 (the delta method's regime) the
    // mean squared error matches the predicted variance: the counts' own (signal + dark) noise,
    // the mean of the flats, and the one dark frame subtracted from both. Everywhere, the mean
    // error (bias) is small against the noise.
    let variance = |mean: f64| {
        (mean + DARK) / (mean * mean)
            + (I0 + DARK) / (FLATS as f64 * I0 * I0)
            + DARK * (1.0 / mean - 1.0 / I0).powi(2)
    };
    let (mut se, mut predicted, mut counted) = (0.0, 0.0, 0usize);
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, &pos) in s.split.train.iter().enumerate() {
        let v = i * VIEWS / 50;
        assert!((s.geometry.angles_rad[pos] - full[v]).abs() < 1e-12);
        for c in 0..s.n_channels() {
            for r in 0..rows {
                for k in 0..cols {
                    let p = truth.projections[[c, v, r, k]] as f64;
                    let d = s.projections[[c, pos, r, k]] as f64 - p;
                    sum += d;
                    n += 1;
                    let mean = I0 * (-p).exp();
                    if mean >= 1000.0 {
                        se += d * d;
                        predicted += variance(mean);
                        counted += 1;
                    }
                }
            }
        }
    }
    let (mse, var, bias) = (
        se / counted as f64,
        predicted / counted as f64,
        sum / n as f64,
    );
    eprintln!(
        "line integrals: MSE {mse:.3e} vs predicted variance {var:.3e} over {counted} of {n} \
         values; bias {bias:.2e}"
    );
    assert!(counted > n / 2, "{counted} of {n}");
    assert!(
        mse > 0.8 * var && mse < 1.25 * var,
        "MSE {mse:.3e} vs predicted variance {var:.3e}"
    );
    assert!(bias.abs() < 1e-3, "bias {bias:.2e}");
    // The reference: FDK of all 360 views, close to the simulated volume.
    let refs = s.references.as_ref().expect("a full-view FDK reference");
    let truth_refs = truth.references.as_ref().unwrap();
    let (num, den) = refs
        .iter()
        .zip(truth_refs.iter())
        .fold((0.0, 0.0), |(a, b), (x, y)| {
            (a + ((x - y) as f64).powi(2), b + (*y as f64).powi(2))
        });
    let rel = (num / den).sqrt();
    eprintln!("full-view FDK reference: relative L2 error {rel:.3} against the simulated volume");
    assert!(rel < 0.25, "relative L2 {rel:.3}");
    // 4D-SG trains on the imported scene like on any other.
    let recon = dir.path().join("4dsg.yaml");
    std::fs::write(
        &recon,
        "method: 4dsg\niterations: 10\neval_every: 0\ninit: {n_points: 200}\ndensify: null\n\
         stage2: {iterations: 4, curve_model: {width: 8, depth: 1, table_size: 64}}\n",
    )
    .unwrap();
    let run = dir.path().join("run");
    let (ok, t) = prism(&["recon", path(&recon), "-s", path(&out), "-o", path(&run)]);
    assert!(ok && run.join("metrics.json").is_file(), "{t}");
}

#[test]
fn a_fan_beam_matlab_sinogram_imports_with_each_channels_reference_method() {
    // The MATLAB v7.3 fixture: a 3-view × 4-column sinogram, value 100·view + column, stored
    // column-major (x:theta). Two channels read it; the first is referenced by FDK (its own
    // `reference`), the second by the import's shared reference, TV started from the FDK.
    let dir = tempfile::tempdir().unwrap();
    let mat = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../crates/domain/tests/fixtures/hdf5/matlab73.mat");
    std::fs::write(dir.path().join("fdk.yaml"), "method: fdk\n").unwrap();
    std::fs::write(
        dir.path().join("tv.yaml"),
        "method: tv\nstart: fdk\niterations: 5\nnonneg: true\ntv: { weight: 0.1, coupling: channel }\n",
    )
    .unwrap();
    let source = format!(
        "{{ path: {}, dataset: /CtData/sinogram, axes: \"x:theta\" }}",
        mat.display()
    );
    let config = dir.path().join("scan.yaml");
    std::fs::write(
        &config,
        format!(
            "name: fan\ngeometry:\n  fan: {{ dso: 50.0, dsd: 80.0, cols: 4, pitch: 2.0, nx: 6, ny: 6, dx: 1.5, dy: 1.5 }}\n\
             angles: {{ count: 3 }}\nchannels:\n\
             \x20 - {{ label: a, coordinate: {{ kind: tube_voltage, kvp: 50 }}, line_integrals: {source}, reference: fdk.yaml }}\n\
             \x20 - {{ label: b, coordinate: {{ kind: tube_voltage, kvp: 80 }}, line_integrals: {source} }}\n\
             select: {{ views: 3, reference: {{ recon: tv.yaml }} }}\n"
        ),
    )
    .unwrap();
    let out = dir.path().join("scene");
    let (ok, t) = prism(&[
        "import",
        path(&config),
        "-o",
        path(&out),
        "--set",
        "select.views=2",
    ]);
    assert!(ok, "{t}");
    assert!(t.contains("references: full-view fdk.yaml, tv.yaml"), "{t}");
    let scene = Scene::load(&out).unwrap();
    let g = &scene.geometry;
    assert_eq!((g.detector.rows, g.volume.nz, scene.n_views()), (1, 1, 2));
    assert_eq!(scene.provenance.overrides, ["select.views=2"]);
    // Views 0 and 1 of 3 (⌊i·3/2⌋), both channels, in the stored order.
    for c in 0..2 {
        for (k, v) in [0usize, 1].into_iter().enumerate() {
            for col in 0..4 {
                let want = (100 * v + col) as f32;
                assert_eq!(scene.projections[[c, k, 0, col]], want);
            }
        }
    }
    let refs = scene.references.as_ref().expect("references");
    let (fdk, tv) = (
        refs.index_axis(ndarray::Axis(0), 0),
        refs.index_axis(ndarray::Axis(0), 1),
    );
    assert!(tv.iter().all(|&x| x >= 0.0), "non-negative TV");
    assert!(
        fdk.iter().zip(tv.iter()).any(|(a, b)| a != b),
        "FDK and TV references differ"
    );
}

#[test]
fn a_reference_volume_from_a_file_is_the_channels_reference_exactly() {
    // A published protocol's own reference: channel `a` reads its [nz, ny, nx] volume from a
    // file, channel `b` keeps the shared FDK. A file not on the grid names itself and the field;
    // a channel giving both a recon config and a volume is refused.
    let dir = tempfile::tempdir().unwrap();
    let mat = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../crates/domain/tests/fixtures/hdf5/matlab73.mat");
    let volume = ndarray::Array3::from_shape_fn((1, 6, 6), |(_, y, x)| 0.01 * (6 * y + x) as f32);
    ndarray_npy::write_npy(dir.path().join("ref.npy"), &volume).unwrap();
    ndarray_npy::write_npy(
        dir.path().join("small.npy"),
        &ndarray::Array3::<f32>::zeros((1, 5, 6)),
    )
    .unwrap();
    std::fs::write(dir.path().join("fdk.yaml"), "method: fdk\n").unwrap();
    let config = dir.path().join("scan.yaml");
    let write = |a_reference: &str| {
        let source = format!(
            "{{ path: {}, dataset: /CtData/sinogram, axes: \"x:theta\" }}",
            mat.display()
        );
        std::fs::write(
            &config,
            format!(
                "name: fan\ngeometry:\n  fan: {{ dso: 50.0, dsd: 80.0, cols: 4, pitch: 2.0, nx: 6, ny: 6, dx: 1.5, dy: 1.5 }}\n\
                 angles: {{ count: 3 }}\nchannels:\n\
                 \x20 - {{ label: a, coordinate: {{ kind: tube_voltage, kvp: 50 }}, line_integrals: {source}, {a_reference} }}\n\
                 \x20 - {{ label: b, coordinate: {{ kind: tube_voltage, kvp: 80 }}, line_integrals: {source} }}\n\
                 select: {{ views: 2 }}\n"
            ),
        )
        .unwrap();
    };
    let out = dir.path().join("scene");
    write("reference_volume: { path: ref.npy }");
    let (ok, t) = prism(&["import", path(&config), "-o", path(&out)]);
    assert!(ok, "{t}");
    assert!(
        t.contains("references: full-view FDK; read from ref.npy"),
        "{t}"
    );
    let scene = Scene::load(&out).unwrap();
    let refs = scene.references.as_ref().expect("references");
    assert_eq!(refs.index_axis(ndarray::Axis(0), 0), volume);
    assert!(
        refs.index_axis(ndarray::Axis(0), 1)
            .iter()
            .any(|&x| x != 0.0)
    );
    write("reference_volume: { path: small.npy }");
    let (ok, t) = prism(&["import", path(&config), "-o", path(&dir.path().join("s2"))]);
    assert!(!ok, "{t}");
    assert!(
        t.contains("small.npy")
            && t.contains("channels[0].reference_volume")
            && t.contains("[1, 6, 6]"),
        "{t}"
    );
    write("reference: fdk.yaml, reference_volume: { path: ref.npy }");
    let (ok, t) = prism(&["import", path(&config), "-o", path(&dir.path().join("s3"))]);
    assert!(
        !ok && t.contains("channels[0].reference_volume") && t.contains("not both"),
        "{t}"
    );
}

#[test]
fn an_off_centre_axis_is_estimated_recorded_and_used_by_the_reference() {
    // A cone-beam scan simulated with its detector shifted by 2.5 columns, imported with a
    // geometry that claims no shift: `prism axis` and `axis: opposing` find the shift to ¼
    // column (the estimators' own accuracy is tested in prism-recon; this checks the wiring:
    // the estimate reaches the scene's geometry, its provenance and its FDK reference).
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("p.yaml");
    std::fs::write(&cfg, phantom_config("p", 120, 16, 25, &[70])).unwrap();
    let pitch = 512.0 / 25.0;
    let truth_dir = dir.path().join("truth");
    let shift = format!("geometry.detector.offset_mm=[{}, 0]", 2.5 * pitch);
    let (ok, t) = prism(&[
        "simulate",
        path(&cfg),
        "-o",
        path(&truth_dir),
        "--set",
        &shift,
    ]);
    assert!(ok, "{t}");
    let truth = Scene::load(&truth_dir).unwrap();
    let g = &truth.geometry;
    assert!((g.detector.offset_u - 2.5 * pitch).abs() < 1e-9);
    let p = truth.projections.index_axis(ndarray::Axis(0), 0).to_owned();
    ndarray_npy::write_npy(dir.path().join("p.npy"), &p).unwrap();
    let mut centred = g.detector.clone();
    centred.offset_u = 0.0;
    let degrees: Vec<String> = g
        .angles_rad
        .iter()
        .map(|a| format!("{}", a.to_degrees()))
        .collect();
    let import = dir.path().join("import.yaml");
    std::fs::write(
        &import,
        format!(
            "name: shifted\ngeometry: {{prism: {{beam: cone, dso: {}, dsd: {}, detector: {}, volume: {}}}}}\n\
             angles: {{deg: [{}]}}\naxis: {{method: opposing, range_px: 6}}\n\
             channels:\n  - {{label: a, coordinate: {{kind: energy, kev: 70}}, line_integrals: {{path: p.npy}}}}\n",
            g.dso,
            g.dsd,
            serde_json::to_string(&centred).unwrap(),
            serde_json::to_string(&g.volume).unwrap(),
            degrees.join(", ")
        ),
    )
    .unwrap();
    let (ok, t) = prism(&["axis", path(&import)]);
    assert!(ok && t.contains("by opposing views"), "{t}");
    let column = 12.0 - 2.5;
    let printed: f64 = t
        .split("onto column ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|c| c.parse().ok())
        .expect("the column is printed");
    assert!((printed - column).abs() < 0.25, "{t}");
    let out = dir.path().join("scene");
    let (ok, t) = prism(&["import", path(&import), "-o", path(&out)]);
    assert!(ok, "{t}");
    let scene = Scene::load(&out).unwrap();
    let estimate = scene
        .provenance
        .axis
        .as_ref()
        .expect("the estimate is recorded");
    assert!((estimate.offset_px - 2.5).abs() < 0.25, "{estimate:?}");
    assert_eq!(scene.geometry.detector.offset_u, estimate.offset_u);
    assert_eq!(estimate.given_offset_u, 0.0);
    let (ok, t) = prism(&["info", path(&out)]);
    assert!(
        ok && t.contains("rotation axis") && t.contains("by opposing views"),
        "{t}"
    );
    // The reference is the FDK on the estimated geometry: nearer the phantom than the FDK with
    // the axis left at the centre, whose edges are doubled.
    let given = dir.path().join("given");
    let (ok, t) = prism(&[
        "import",
        path(&import),
        "-o",
        path(&given),
        "--set",
        "axis=given",
    ]);
    assert!(ok, "{t}");
    let given = Scene::load(&given).unwrap();
    assert!(given.provenance.axis.is_none());
    let phantom = truth.references.as_ref().unwrap();
    let err = |s: &Scene| {
        let r = s.references.as_ref().unwrap();
        r.iter()
            .zip(phantom)
            .map(|(x, y)| ((x - y) as f64).powi(2))
            .sum::<f64>()
    };
    assert!(
        err(&scene) < 0.5 * err(&given),
        "{} vs {}",
        err(&scene),
        err(&given)
    );
}

#[test]
fn a_scan_given_by_per_view_vectors_imports_and_every_method_runs_on_it() {
    // A disturbed cone-beam scan (source wobble, detector spin, tilt and shift per view) as
    // ASTRA rows, two channels of exact line integrals. `prism import` keeps the vectors (no
    // angles given: they are derived), and FDK, SART, R²-Gaussian, 4D-SG and NAF each train
    // and score on it.
    use prism_domain::geometry::Beam;
    use prism_domain::testing::{analytic_projections, geometry, phantom, wobbled};
    let dir = tempfile::tempdir().unwrap();
    let g = wobbled(&geometry(Beam::Cone, 12, 16, 24, false));
    let rows: Vec<f64> = g
        .to_vectors()
        .into_iter()
        .flat_map(<[f64; 12]>::from)
        .collect();
    let vectors = ndarray::Array2::from_shape_vec((g.views(), 12), rows).unwrap();
    ndarray_npy::write_npy(dir.path().join("vectors.npy"), &vectors).unwrap();
    let objs = phantom(5.0);
    for (name, k) in [("lo", 1.0f32), ("hi", 0.7)] {
        let p = analytic_projections(&g, &objs).mapv(|x| x * k);
        ndarray_npy::write_npy(dir.path().join(format!("{name}.npy")), &p).unwrap();
    }
    let config = dir.path().join("scan.yaml");
    std::fs::write(
        &config,
        "name: wobble\ngeometry:\n  vectors: { beam: cone, file: vectors.npy, rows: 16, cols: 16, \
         volume: { nx: 12, ny: 12, nz: 12, dx: 1.0, dy: 1.0, dz: 1.0 } }\nchannels:\n\
         \x20 - { label: lo, coordinate: { kind: tube_voltage, kvp: 80 }, line_integrals: { path: lo.npy } }\n\
         \x20 - { label: hi, coordinate: { kind: tube_voltage, kvp: 140 }, line_integrals: { path: hi.npy } }\n\
         select: { views: 12, test_views: 2 }\n",
    )
    .unwrap();
    let scene = dir.path().join("scene");
    let (ok, t) = prism(&["import", path(&config), "-o", path(&scene)]);
    assert!(ok, "{t}");
    let s = Scene::load(&scene).unwrap();
    let kept = s.geometry.vectors.as_ref().expect("vectors kept");
    assert_eq!(kept.len(), 14);
    // Training views 0, 2, 4, … and test views 1 and 13 of the 24, in scan order.
    let all = g.to_vectors();
    assert_eq!((kept[1], kept[3], kept[8]), (all[1], all[4], all[13]));
    let (ok, t) = prism(&["info", path(&scene)]);
    assert!(ok && t.contains("per-view vectors"), "{t}");
    let methods = [
        ("fdk", "method: fdk\n"),
        ("sart", "method: sart\niterations: 3\n"),
        (
            "r2gs",
            "method: r2gs\niterations: 20\ninit: { n_points: 200 }\neval_every: 0\n",
        ),
        (
            "4dsg",
            "method: 4dsg\niterations: 15\ninit: { n_points: 200 }\neval_every: 0\n\
             stage2: { iterations: 10, curve_model: { width: 8, depth: 1 } }\n",
        ),
        (
            "naf",
            "method: naf\niterations: 4\nrays_per_batch: 64\nsamples_per_ray: 16\neval_every: 4\n",
        ),
    ];
    for (name, text) in methods {
        let cfg = dir.path().join(format!("{name}.yaml"));
        std::fs::write(&cfg, text).unwrap();
        let out = dir.path().join(format!("run-{name}"));
        let (ok, t) = prism(&["recon", path(&cfg), "-s", path(&scene), "-o", path(&out)]);
        assert!(ok, "{name}: {t}");
        let metrics = std::fs::read_to_string(out.join("metrics.json")).unwrap();
        assert!(metrics.contains("psnr"), "{name}: {metrics}");
    }
}
