//! Unit checks of the import steps; the round trip from simulated counts is
//! `tests/cli_import.rs`.

use super::config::*;
use super::*;
use ndarray::{Array2, Array3};

fn config(yaml: &str) -> ImportConfig {
    serde_yaml_ng::from_str(yaml).unwrap()
}

const BASE: &str = "name: t\ngeometry: {prism: {beam: cone, dso: 100.0, dsd: 150.0, \
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
    };
    let a = images::read_stack(&src("le.raw", false, 0), dir.path()).unwrap();
    let b = images::read_stack(&src("be.raw", true, 16), dir.path()).unwrap();
    assert_eq!(a.shape(), [1, 2, 3]);
    assert_eq!(a, b);
    assert_eq!(a[[0, 1, 2]], 65535.0);
    let e = images::read_stack(&src("be.raw", true, 0), dir.path())
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
