//! Unit checks of the detector repairs of an import: bad pixels and ring (stripe) suppression.

use super::tests::{BASE, config};
use super::*;
use ndarray::{Array2, Array3};

/// The middle row of a parallel-beam scan of the test phantom over half a turn: `[views][cols]`
/// line integrals.
fn clean_sinogram(views: usize, cols: usize) -> Array2<f32> {
    use crate::geometry::{Beam, Geometry};
    use crate::testing::{analytic_projections, geometry, phantom};
    let mut g = geometry(Beam::Parallel, 32, cols, views, false);
    g.detector.rows = 1;
    g.angles_rad = Geometry::uniform_angles(views, 0.0, std::f64::consts::PI);
    let p = analytic_projections(&g, &phantom(14.0));
    p.index_axis(ndarray::Axis(1), 0).to_owned()
}

#[test]
fn sorting_removes_full_and_partial_stripes_and_keeps_a_clean_sinogram() {
    use super::rings::{RingConfig, RingMethod};
    let (views, cols) = (180, 192);
    let clean = clean_sinogram(views, cols);
    let t = clean.mapv(|p| (-p).exp());
    // Gain errors on the transmission (the object spans columns 55–140): full stripes in the air
    // and, two columns wide, in the object, a dark one, and one present in a third of the views
    // only (a pixel that drifted during the scan).
    let mut striped = t.clone();
    for v in 0..views {
        striped[[v, 20]] *= 1.05;
        striped[[v, 80]] *= 1.05;
        striped[[v, 81]] *= 1.05;
        striped[[v, 100]] *= 0.96;
        if (60..120).contains(&v) {
            striped[[v, 115]] *= 1.08;
        }
    }
    let rings = RingConfig {
        method: RingMethod::Sorting,
        size: 21,
    };
    let filter = |a: &Array2<f32>| {
        let mut s = a.clone().insert_axis(ndarray::Axis(1));
        rings.apply(&mut s).unwrap();
        s.index_axis(ndarray::Axis(1), 0).mapv(|x| -x.ln())
    };
    // The stripe left in column c: its mean line-integral error over `range` against the clean
    // sinogram, less its neighbours' (c ± 3; what the filter changes in unstriped columns too,
    // measured below, is not a stripe).
    let stripe = |p: &Array2<f32>, c: usize, range: std::ops::Range<usize>| {
        let n = range.len() as f64;
        let mean = |c: usize| {
            range
                .clone()
                .map(|v| (p[[v, c]] - clean[[v, c]]) as f64)
                .sum::<f64>()
                / n
        };
        mean(c) - 0.5 * (mean(c - 3) + mean(c + 3))
    };
    let before = striped.mapv(|x| -x.ln());
    let after = filter(&striped);
    let stripes = [
        (20, 0..views),
        (80, 0..views),
        (81, 0..views),
        (100, 0..views),
        (115, 60..120),
    ];
    for (c, range) in stripes {
        let (b, a) = (stripe(&before, c, range.clone()), stripe(&after, c, range));
        eprintln!("column {c}: stripe {b:+.5} → {a:+.5}");
        // |ln 1.05| = 0.049, |ln 0.96| = 0.041, |ln 1.08| = 0.077 before; a tenth at most after.
        assert!(a.abs() < 0.1 * b.abs(), "column {c}: {b} → {a}");
    }
    // A sinogram without stripes changes little: object edges move across columns with the
    // view and mostly survive the sorted median (1.3 % here, on the phantom's perfectly sharp
    // edges sampled by 192 columns).
    let kept = filter(&t);
    let num: f64 = kept
        .iter()
        .zip(&clean)
        .map(|(a, b)| ((a - b) as f64).powi(2))
        .sum();
    let den: f64 = clean.iter().map(|b| (*b as f64).powi(2)).sum();
    let change = (num / den).sqrt();
    eprintln!("clean sinogram changed by {change:.4} (relative L2)");
    assert!(change < 0.02, "{change}");
}

#[test]
fn ring_window_is_checked_by_field() {
    let base = format!("{BASE}angles: {{count: 4}}\nchannels: []\n");
    for (size, ok) in [("21", false), ("3", true), ("4", false), ("1", false)] {
        // The detector has 3 columns: only a 3-wide window fits.
        let c = config(&format!("{base}rings: {{size: {size}}}\n"));
        let r = c.rings.as_ref().unwrap().validate(3);
        assert_eq!(r.is_ok(), ok, "{size}");
        if let Err(e) = r {
            assert!(e.to_string().contains("rings.size"), "{e}");
        }
    }
    assert_eq!(
        config(&format!("{base}rings: {{}}\n")).rings.unwrap().size,
        21
    );
}

#[test]
fn bad_pixels_are_found_in_the_open_beam_and_repaired_before_the_log() {
    // A smooth object; a dead pixel (open beam 0: flat = dark = counts) and a hot one (its flat
    // three times its neighbours', its response to the object normal: flat-field correction
    // would add ln 3 there). Repaired, both are their good neighbours' median: within the
    // object's change over the 5 × 5 window (≤ 0.06 here); every other pixel is unchanged.
    let (views, rows, cols) = (3, 8, 12);
    let dark = 50.0f32;
    let truth =
        |v: usize, r: usize, c: usize| 0.2 + 0.01 * c as f32 + 0.02 * r as f32 + 0.01 * v as f32;
    let open = |c: usize| 1000.0 * (1.0 + 0.02 * c as f32);
    let mut flat = Array2::from_shape_fn((rows, cols), |(_, c)| dark + open(c));
    let counts = Array3::from_shape_fn((views, rows, cols), |(v, r, c)| {
        if (r, c) == (2, 3) {
            dark
        } else {
            dark + open(c) * (-truth(v, r, c)).exp()
        }
    });
    flat[[2, 3]] = dark;
    flat[[5, 7]] = dark + 3.0 * open(7);
    let dir = tempfile::tempdir().unwrap();
    ndarray_npy::write_npy(dir.path().join("counts.npy"), &counts).unwrap();
    ndarray_npy::write_npy(dir.path().join("flat.npy"), &flat).unwrap();
    ndarray_npy::write_npy(
        dir.path().join("dark.npy"),
        &Array2::from_elem((rows, cols), dark),
    )
    .unwrap();
    let text = |extra: &str| {
        format!(
            "name: t\ngeometry: {{prism: {{beam: parallel, dso: 100.0, dsd: 150.0, \
             detector: {{rows: 8, cols: 12, pitch_u: 1.0, pitch_v: 1.0}}, \
             volume: {{nx: 4, ny: 4, nz: 4, dx: 1.0, dy: 1.0, dz: 1.0}}}}}}\n\
             angles: {{count: 3}}\nflat: {{path: flat.npy}}\ndark: {{path: dark.npy}}\n{extra}\
             channels:\n  - {{label: a, coordinate: {{kind: tube_voltage, kvp: 80}}, \
             counts: {{path: counts.npy}}}}\n"
        )
    };
    // Without repair the dead pixel is an error naming it.
    let plain = text("");
    let e = assemble(&config(&plain), dir.path(), &plain)
        .unwrap_err()
        .to_string();
    assert!(e.contains("flat[2][3]"), "{e}");
    let repaired = text("bad_pixels: {}\n");
    let c = config(&repaired);
    let found = c
        .bad_pixels
        .as_ref()
        .unwrap()
        .find((&flat - dark).view())
        .unwrap();
    let marked: Vec<(usize, usize)> = found
        .indexed_iter()
        .filter(|(_, b)| **b)
        .map(|(p, _)| p)
        .collect();
    assert_eq!(marked, [(2, 3), (5, 7)]);
    let full = assemble(&c, dir.path(), &repaired).unwrap();
    assert_eq!(full.bad_pixels, [2]);
    let p = &full.scene.projections;
    for v in 0..views {
        for r in 0..rows {
            for col in 0..cols {
                let err = (p[[0, v, r, col]] - truth(v, r, col)).abs();
                let tol = if marked.contains(&(r, col)) {
                    0.06
                } else {
                    1e-5
                };
                assert!(err < tol, "view {v} pixel ({r}, {col}): {err}");
            }
        }
    }
    // Its settings are checked by field.
    let bad = text("bad_pixels: {max_deviation: 0.0}\n");
    let e = assemble(&config(&bad), dir.path(), &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad_pixels.max_deviation"), "{e}");
}
