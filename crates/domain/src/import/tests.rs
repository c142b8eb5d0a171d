//! Unit checks of the import steps; the round trip from simulated counts is
//! `tests/cli_import.rs`.

use super::config::*;
use super::*;
use ndarray::{Array2, Array3};

pub(super) fn config(yaml: &str) -> ImportConfig {
    serde_yaml_ng::from_str(yaml).unwrap()
}

pub(super) const BASE: &str = "name: t\ngeometry: {prism: {beam: cone, dso: 100.0, dsd: 150.0, \
    detector: {rows: 2, cols: 3, pitch_u: 1.0, pitch_v: 1.0}, \
    volume: {nx: 2, ny: 2, nz: 2, dx: 1.0, dy: 1.0, dz: 1.0}}}\n";

#[test]
fn counts_become_line_integrals_with_a_floor_and_a_tally() {
    let flat = Array2::from_elem((2, 3), 1010.0f32);
    let dark = Array2::from_elem((2, 3), 10.0f32);
    let mut counts = Array3::from_elem((2, 2, 3), 10.0 + 1000.0 * (-0.7f32).exp());
    counts[[1, 0, 2]] = 10.0; // zero net counts
    counts[[1, 1, 1]] = 3.0; // negative net counts
    let (p, raised) = line_integrals(counts, flat.view(), dark.view(), 0.5).unwrap();
    assert!((p[[0, 1, 2]] - 0.7).abs() < 1e-5, "{}", p[[0, 1, 2]]);
    assert_eq!(raised, 2);
    let floor = -(0.5f64 / 1000.0).ln() as f32;
    assert_eq!((p[[1, 0, 2]], p[[1, 1, 1]]), (floor, floor));
    // No beam at a pixel: refused, naming it.
    let mut bad = flat.clone();
    bad[[1, 2]] = 10.0;
    let e = line_integrals(Array3::ones((1, 2, 3)), bad.view(), dark.view(), 0.5)
        .unwrap_err()
        .to_string();
    assert!(e.contains("flat[1][2]") && e.contains("F − D = 0"), "{e}");
}

#[test]
fn views_are_picked_evenly_and_test_views_from_the_rest() {
    let mut c = config(&format!(
        "{BASE}angles: {{count: 360}}\nchannels: []\nselect: {{views: 50, test_views: 20}}\n"
    ));
    let (train, test) = c.pick_views(360).unwrap();
    assert_eq!(train.len(), 50);
    assert_eq!(&train[..6], [0, 7, 14, 21, 28, 36]);
    assert_eq!(test.len(), 20);
    assert!(test.iter().all(|v| train.binary_search(v).is_err()));
    assert!(test.windows(2).all(|w| w[0] < w[1]));
    c.select.views = None;
    c.select.every = Some(90);
    c.select.test_views = 0;
    assert_eq!(c.pick_views(360).unwrap().0, [0, 90, 180, 270]);
    c.select.views = Some(400);
    c.select.every = None;
    let e = c.pick_views(360).unwrap_err().to_string();
    assert!(e.contains("select.views") && e.contains("360"), "{e}");
}

#[test]
fn angles_come_evenly_listed_or_from_a_file_with_a_unit() {
    let none = |_: &Path| -> Result<Vec<f64>> { Ok(vec![0.0, 90.0]) };
    let a = AngleSpec {
        count: Some(4),
        ..AngleSpec::default()
    };
    let r = a.resolve(none).unwrap();
    assert!((r[1] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    let f = AngleSpec {
        file: Some("a.txt".into()),
        ..AngleSpec::default()
    };
    let e = f.resolve(none).unwrap_err().to_string();
    assert!(e.contains("angles.unit"), "{e}");
    let f = AngleSpec {
        unit: Some(AngleUnit::Deg),
        ..f
    };
    assert_eq!(f.resolve(none).unwrap()[1], 90f64.to_radians());
    let both = AngleSpec {
        count: Some(3),
        deg: Some(vec![1.0]),
        ..AngleSpec::default()
    };
    assert!(
        both.resolve(none)
            .unwrap_err()
            .to_string()
            .contains("exactly one")
    );
}

#[test]
fn raw_files_are_read_in_either_byte_order_and_their_size_is_checked() {
    let dir = tempfile::tempdir().unwrap();
    let values: [u16; 6] = [1, 2, 300, 4, 5, 65535];
    let le: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    let be: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    let mut with_header = vec![7u8; 16];
    with_header.extend(&be);
    std::fs::write(dir.path().join("le.raw"), &le).unwrap();
    std::fs::write(dir.path().join("be.raw"), &with_header).unwrap();
    let src = |file: &str, big_endian: bool, header_bytes: u64| ImageSource {
        path: file.into(),
        raw: Some(RawLayout {
            dtype: RawType::U16,
            shape: vec![2, 3],
            big_endian,
            header_bytes,
        }),
        dataset: None,
        axes: None,
    };
    let a = images::read_stack(&src("le.raw", false, 0), dir.path(), None).unwrap();
    let b = images::read_stack(&src("be.raw", true, 16), dir.path(), None).unwrap();
    assert_eq!(a.shape(), [1, 2, 3]);
    assert_eq!(a, b);
    assert_eq!(a[[0, 1, 2]], 65535.0);
    let e = images::read_stack(&src("be.raw", true, 0), dir.path(), None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("be.raw") && e.contains("raw.shape") && e.contains("28"),
        "{e}"
    );
}

#[test]
fn partial_channels_are_unavailable_where_they_were_not_measured_and_views_subset() {
    let dir = tempfile::tempdir().unwrap();
    let p = Array3::from_shape_fn((4, 2, 3), |(v, r, c)| (v * 100 + r * 10 + c) as f32);
    ndarray_npy::write_npy(dir.path().join("a.npy"), &p).unwrap();
    ndarray_npy::write_npy(
        dir.path().join("b.npy"),
        &p.slice(s![0..2, .., ..]).to_owned(),
    )
    .unwrap();
    let text = format!(
        "{BASE}angles: {{count: 4}}\nrows_bottom_up: true\nchannels:\n  \
         - {{label: lo, coordinate: {{kind: tube_voltage, kvp: 80}}, line_integrals: {{path: a.npy}}}}\n  \
         - {{label: hi, coordinate: {{kind: tube_voltage, kvp: 140}}, line_integrals: {{path: b.npy}}, views: [1, 3]}}\n"
    );
    let full = assemble(&config(&text), dir.path(), &text).unwrap();
    let s = &full.scene;
    assert_eq!(
        s.availability.column(1).to_vec(),
        [false, true, false, true]
    );
    // Rows flipped: stored row 0 is the bottom, Prism's row 1.
    assert_eq!(s.projections[[0, 2, 1, 0]], 200.0);
    assert_eq!(s.projections[[1, 3, 1, 2]], 102.0); // hi's second image is view 3
    let sub = s.with_views(&[0, 3], &[2]).unwrap();
    assert_eq!(sub.n_views(), 3);
    assert_eq!(sub.split.train, [0, 2]);
    assert_eq!(sub.split.test, [1]);
    assert_eq!(sub.geometry.angles_rad[1], s.geometry.angles_rad[2]);
    assert_eq!(sub.projections[[0, 2, 1, 0]], 300.0);
    assert!(sub.provenance.generator.starts_with("prism import"));
    // A channel with images but no beam reference is refused by field.
    let bad = text.replace("line_integrals: {path: a.npy}", "counts: {path: a.npy}");
    let e = assemble(&config(&bad), dir.path(), &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("channels[0].flat"), "{e}");
}

#[test]
fn clip_negative_sets_negative_line_integrals_to_zero_and_counts_them() {
    // Two channels: line integrals with three negative values, and counts brighter than their
    // flat at one pixel (p = −ln 2 < 0). Kept by default, zero with `clip_negative`.
    let dir = tempfile::tempdir().unwrap();
    let mut p = Array3::from_shape_fn((2, 2, 3), |(v, r, c)| 0.1 * (v + r + c) as f32);
    for (i, x) in [-0.02f32, -1e-6, -0.5].into_iter().enumerate() {
        p[[i % 2, 1, i]] = x;
    }
    ndarray_npy::write_npy(dir.path().join("li.npy"), &p).unwrap();
    let mut counts = Array3::from_elem((2, 2, 3), 50.0f32);
    counts[[1, 0, 2]] = 200.0;
    ndarray_npy::write_npy(dir.path().join("i.npy"), &counts).unwrap();
    ndarray_npy::write_npy(
        dir.path().join("f.npy"),
        &Array2::from_elem((2, 3), 100.0f32),
    )
    .unwrap();
    let text = |extra: &str| {
        format!(
            "{BASE}angles: {{count: 2}}\nflat: {{path: f.npy}}\n{extra}channels:\n  \
             - {{label: a, coordinate: {{kind: tube_voltage, kvp: 80}}, line_integrals: {{path: li.npy}}}}\n  \
             - {{label: b, coordinate: {{kind: tube_voltage, kvp: 140}}, counts: {{path: i.npy}}}}\n"
        )
    };
    let kept = assemble(&config(&text("")), dir.path(), &text("")).unwrap();
    assert_eq!(kept.clipped, [0, 0]);
    let (a, b) = (kept.scene.projections, text("clip_negative: true\n"));
    assert_eq!(a[[0, 0, 1, 2]], -0.5);
    assert!((a[[1, 1, 0, 2]] + 2f32.ln()).abs() < 1e-6);
    let clipped = assemble(&config(&b), dir.path(), &b).unwrap();
    assert_eq!(clipped.clipped, [3, 1]);
    let c = &clipped.scene.projections;
    // Exactly the negative values changed, to zero; every other value is the same.
    for (x, y) in a.iter().zip(c.iter()) {
        assert_eq!(*y, if *x < 0.0 { 0.0 } else { *x });
    }
}

fn hdf5_fixture() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/hdf5")
}

#[test]
fn per_view_vectors_read_from_hdf5_and_matlab_in_f64() {
    // Fixtures from tests/fixtures/hdf5/make_fixtures.py: value = 100·view + j + 1e-7·(j + 1),
    // whose fraction float32 would lose.
    let base = hdf5_fixture();
    let want = |rows: &[Vec<f64>]| {
        rows.len() == 3
            && rows.iter().enumerate().all(|(v, r)| {
                r.len() == 12
                    && r.iter()
                        .enumerate()
                        .all(|(j, &x)| x == 100.0 * v as f64 + j as f64 + 1e-7 * (j + 1) as f64)
            })
    };
    let h5 = super::read_vector_rows(
        &base.join("dataexchange.h5"),
        Some("/geometry/vectors"),
        None,
        12,
    )
    .unwrap();
    assert!(want(&h5), "{h5:?}");
    // MATLAB -v7.3 stores its views × 12 matrix column-major: `x:theta`.
    let mat = super::read_vector_rows(
        &base.join("matlab73.mat"),
        Some("/CtData/vectors"),
        Some("x:theta"),
        12,
    )
    .unwrap();
    assert!(want(&mat), "{mat:?}");
    // Read views first, the shape [12, 3] names the mismatch; no dataset, or one on a text
    // file, is refused naming the field.
    let e = super::read_vector_rows(
        &base.join("matlab73.mat"),
        Some("/CtData/vectors"),
        None,
        12,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("3 numbers per view, not 12") && e.contains("set `axes`"),
        "{e}"
    );
    let e = super::read_vector_rows(&base.join("matlab73.mat"), None, None, 12)
        .unwrap_err()
        .to_string();
    assert!(e.contains("dataset"), "{e}");
    let e = super::read_vector_rows(&base.join("make_fixtures.py"), Some("/v"), None, 12)
        .unwrap_err()
        .to_string();
    assert!(e.contains("not one"), "{e}");
}

#[test]
fn hdf5_stacks_come_out_views_rows_columns_in_any_stored_order() {
    // Fixtures from tests/fixtures/hdf5/make_fixtures.py: value = 100·view + 10·row + col.
    let base = hdf5_fixture();
    let src = |path: &str, dataset: &str, axes: Option<&str>| ImageSource {
        path: path.into(),
        raw: None,
        dataset: Some(dataset.into()),
        axes: axes.map(Into::into),
    };
    let closed_form = |a: &Array3<f32>| {
        a.indexed_iter()
            .all(|((v, r, c), &x)| x == (100 * v + 10 * r + c) as f32)
    };
    // Data Exchange: chunked, gzip + shuffle, order from the `axes` attribute.
    let a =
        images::read_stack(&src("dataexchange.h5", "/exchange/data", None), &base, None).unwrap();
    assert_eq!(a.shape(), [3, 2, 4]);
    assert!(closed_form(&a), "{a:?}");
    // An integer stack without an `axes` attribute: theta:y:x by default.
    let w = images::read_stack(
        &src("dataexchange.h5", "exchange/data_white", None),
        &base,
        None,
    )
    .unwrap();
    assert_eq!(w.shape(), [2, 2, 4]);
    assert!(closed_form(&w));
    // MATLAB v7.3 (512-byte user block): a views × cols sinogram stored column-major.
    let m = images::read_stack(
        &src("matlab73.mat", "/CtData/sinogram", Some("x:theta")),
        &base,
        None,
    )
    .unwrap();
    assert_eq!(m.shape(), [3, 1, 4]);
    assert!(closed_form(&m), "{m:?}");
    // Read in the wrong order, the shape says so; a missing dataset lists the file's datasets.
    let t = images::read_stack(
        &src("matlab73.mat", "/CtData/sinogram", Some("theta:x")),
        &base,
        None,
    )
    .unwrap();
    assert_eq!(t.shape(), [4, 1, 3]);
    let e = images::read_stack(&src("dataexchange.h5", "/exchange/dta", None), &base, None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("dataexchange.h5") && e.contains("/exchange/data [3, 2, 4]"),
        "{e}"
    );
    let no_dataset = ImageSource {
        dataset: None,
        ..src("dataexchange.h5", "", None)
    };
    let e = images::read_stack(&no_dataset, &base, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("needs the dataset's path"), "{e}");
    // Angles from a dataset.
    let th = read_angles(&base.join("dataexchange.h5"), Some("/exchange/theta")).unwrap();
    assert_eq!(th, [0.0, 60.0, 120.0]);
    assert!(read_angles(&base.join("dataexchange.h5"), None).is_err());
}

/// A fan-beam scan's projections by hand: the source at `dso·(cos θ, sin θ)`, column `c` of the
/// flat detector line at `u = (c + ½ − cols/2)·pitch + offset_u` along `(−sin θ, cos θ)`,
/// `dsd` from the source; the chord of each (z-infinite) ellipse from source to detector.
pub(super) fn fan_truth(
    f: &FanGeometry,
    angles: &[f64],
    objs: &[crate::testing::Ellipsoid],
) -> Array3<f32> {
    Array3::from_shape_fn((angles.len(), 1, f.cols), |(v, _, c)| {
        let (s, co) = angles[v].sin_cos();
        let src = [f.dso * co, f.dso * s, 0.0];
        let u = (c as f64 + 0.5 - f.cols as f64 / 2.0) * f.pitch + f.offset_u;
        let det = [
            src[0] - f.dsd * co - u * s,
            src[1] - f.dsd * s + u * co,
            0.0,
        ];
        let d = [det[0] - src[0], det[1] - src[1], 0.0];
        let len = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let dir = [d[0] / len, d[1] / len, 0.0];
        objs.iter().map(|e| e.chord(src, dir, len)).sum::<f64>() as f32
    })
}

#[test]
fn fan_beam_is_one_cone_row_through_one_slice_and_projects_its_line_integrals() {
    use crate::projector::Joseph;
    use crate::testing::{Ellipsoid, rel_l2, voxelise};
    // Cylinders along z: a 2-D object, whatever the slice thickness.
    let objs = [
        Ellipsoid {
            centre: [1.0, -2.0, 0.0],
            axes: [11.0, 8.0, 1e6],
            rho: 0.02,
        },
        Ellipsoid {
            centre: [-3.0, 3.0, 0.0],
            axes: [3.0, 4.5, 1e6],
            rho: 0.05,
        },
    ];
    let angles: Vec<f64> = (0..9).map(|i| 0.3 + i as f64 * 0.7).collect();
    let mut errs = Vec::new();
    for n in [32usize, 64] {
        let f = FanGeometry {
            dso: 120.0,
            dsd: 200.0,
            cols: 80,
            pitch: 0.9,
            offset_u: 1.3,
            nx: n,
            ny: n,
            dx: 32.0 / n as f64,
            dy: 32.0 / n as f64,
            offset: [0.0, 0.0],
            detector: FanDetector::Flat,
        };
        let g = f.to_geometry(angles.clone()).unwrap();
        assert_eq!((g.detector.rows, g.volume.nz), (1, 1));
        assert!((g.volume.dz - 0.9 * 120.0 / 200.0).abs() < 1e-12);
        let a = Joseph::new(&g).unwrap();
        let fp = a.forward(voxelise(&g.volume, &objs, 4).view()).unwrap();
        errs.push(rel_l2(&fp, &fan_truth(&f, &angles, &objs)));
    }
    eprintln!("fan fp vs analytic: {errs:?}");
    // First order in the pixel size at the ellipse boundaries (as the cone test): halving the
    // pixel halves the error.
    assert!(errs[1] < 0.6 * errs[0] && errs[1] < 0.03, "{errs:?}");
    // The fan's own field names in its errors.
    let bad = config(
        "name: t\ngeometry: {fan: {dso: 100.0, dsd: 90.0, cols: 8, pitch: 1.0, nx: 4, ny: 4, \
         dx: 1.0, dy: 1.0}}\nangles: {count: 4}\nchannels: []\n",
    );
    let e = bad.geometry(Some(vec![0.0]), None).unwrap_err().to_string();
    assert!(e.contains("geometry.fan.dsd"), "{e}");
    let bad = config(
        "name: t\ngeometry: {fan: {dso: 100.0, dsd: 190.0, cols: 8, pitch: -1.0, nx: 4, ny: 4, \
         dx: 1.0, dy: 1.0}}\nangles: {count: 4}\nchannels: []\n",
    );
    let e = bad.geometry(Some(vec![0.0]), None).unwrap_err().to_string();
    assert!(e.contains("geometry.fan.pitch"), "{e}");
}

#[test]
fn per_view_vectors_import_from_npy_or_text_rows() {
    use crate::geometry::Beam;
    use crate::projector::Joseph;
    use crate::testing::{geometry, random, wobbled};
    let dir = tempfile::tempdir().unwrap();
    let g = wobbled(&geometry(Beam::Cone, 8, 12, 5, true));
    let rows: Vec<[f64; 12]> = g.to_vectors().into_iter().map(Into::into).collect();
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    let a = Array2::from_shape_vec((rows.len(), 12), flat).unwrap();
    ndarray_npy::write_npy(dir.path().join("vec.npy"), &a).unwrap();
    ndarray_npy::write_npy(dir.path().join("vec32.npy"), &a.mapv(|x| x as f32)).unwrap();
    // Text: full precision (`{:?}` round-trips f64), commas or spaces, comments.
    let text_rows: String = rows
        .iter()
        .map(|r| {
            let cells: Vec<String> = r.iter().map(|x| format!("{x:?}")).collect();
            format!("{}  # a view\n", cells.join(", "))
        })
        .collect();
    std::fs::write(
        dir.path().join("vec.txt"),
        format!("# sx sy sz ...\n{text_rows}"),
    )
    .unwrap();
    let p = random([5, 12, 12], 1).mapv(f32::abs);
    ndarray_npy::write_npy(dir.path().join("li.npy"), &p).unwrap();
    let yaml = |file: &str, extra: &str| {
        format!(
            "name: t\ngeometry: {{vectors: {{beam: cone, file: {file}, rows: 12, cols: 12, \
             volume: {{nx: 8, ny: 8, nz: 8, dx: 1.0, dy: 1.0, dz: 1.0, \
             offset: [0.3, -0.25, 0.2]}}}}}}\n{extra}channels:\n  \
             - {{label: a, coordinate: {{kind: tube_voltage, kvp: 80}}, \
             line_integrals: {{path: li.npy}}}}\n"
        )
    };
    for file in ["vec.npy", "vec.txt"] {
        let text = yaml(file, "");
        let s = assemble(&config(&text), dir.path(), &text).unwrap().scene;
        // Exactly the vectors written; the angles derived from them.
        assert_eq!(s.geometry.vectors, g.vectors, "{file}");
        for (x, y) in s.geometry.angles_rad.iter().zip(&g.angles_rad) {
            assert!((x - y).abs() < 1e-12);
        }
    }
    // f32 rows: the same scan to f32 rounding (the perpendicularity check passes).
    let text = yaml("vec32.npy", "");
    let s = assemble(&config(&text), dir.path(), &text).unwrap().scene;
    let fp = |g: &crate::geometry::Geometry| {
        let x = random(g.volume.shape_zyx(), 2);
        Joseph::new(g).unwrap().forward(x.view()).unwrap()
    };
    assert!(crate::testing::rel_l2(&fp(&s.geometry), &fp(&g)) < 1e-5);
    // Angles, if the config gives them, must be one per row.
    let text = yaml("vec.npy", "angles: {count: 4}\n");
    let e = assemble(&config(&text), dir.path(), &text)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("geometry.vectors.angles") && e.contains("4 angles for 5 views"),
        "{e}"
    );
    // Bad rows name the file and line.
    std::fs::write(dir.path().join("short.txt"), "1 2 3\n").unwrap();
    let text = yaml("short.txt", "");
    let e = assemble(&config(&text), dir.path(), &text)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("short.txt") && e.contains("line 1") && e.contains("12"),
        "{e}"
    );
}

#[test]
fn fan_vectors_are_the_fan_geometry_they_describe() {
    // A circular fan written as ASTRA `fanflat_vec` rows (source, detector centre, u in the
    // plane) imports as the same scan as the `fan:` fields: the same line integrals.
    use crate::projector::Joseph;
    use crate::testing::{random, rel_l2};
    let f = FanGeometry {
        dso: 120.0,
        dsd: 200.0,
        cols: 40,
        pitch: 0.9,
        offset_u: 1.3,
        nx: 16,
        ny: 16,
        dx: 1.5,
        dy: 1.5,
        offset: [0.5, 0.0],
        detector: FanDetector::Flat,
    };
    let angles: Vec<f64> = (0..7).map(|i| 0.3 + i as f64 * 0.9).collect();
    let g = f.to_geometry(angles).unwrap();
    let rows: String = g
        .to_vectors()
        .iter()
        .map(|w| {
            let r = [
                w.source[0],
                w.source[1],
                w.detector[0],
                w.detector[1],
                w.u[0],
                w.u[1],
            ];
            r.map(|x| format!("{x:?}")).join(" ") + "\n"
        })
        .collect();
    let v = VectorGeometry {
        beam: VectorBeam::Fan,
        file: "fan.txt".into(),
        dataset: None,
        axes: None,
        rows: None,
        cols: 40,
        volume: g.volume.clone(),
    };
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("fan.txt"), rows).unwrap();
    let read = super::read_vector_rows(&dir.path().join("fan.txt"), None, None, 6).unwrap();
    let h = v.to_geometry(&read, None).unwrap();
    let x = random(g.volume.shape_zyx(), 3);
    let fp = |g: &crate::geometry::Geometry| Joseph::new(g).unwrap().forward(x.view()).unwrap();
    assert!(rel_l2(&fp(&h), &fp(&g)) < 1e-6);
    // A fan reconstructs one slice.
    let thick = VectorGeometry {
        volume: crate::geometry::VolumeGrid {
            nz: 2,
            ..g.volume.clone()
        },
        ..v
    };
    let e = thick.to_geometry(&read, None).unwrap_err().to_string();
    assert!(e.contains("volume.nz"), "{e}");
}
