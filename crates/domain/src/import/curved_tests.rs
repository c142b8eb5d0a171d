//! Unit checks of curved (equiangular) fan detectors: rebinned onto the flat line the same rays
//! cross, checked against a profile linear in the fan angle (exact) and against line integrals
//! computed by hand along the curved and the flat rays (within the interpolation bound).

use super::tests::config;
use super::*;
use ndarray::Array3;

const DSO: f64 = 120.0;
const DSD: f64 = 200.0;

/// Column `c`'s fan angle on an arc of `cols` columns of `pitch` (mm at DSD), shifted `offset_u`.
fn gamma(c: usize, cols: usize, pitch: f64, offset_u: f64) -> f64 {
    ((c as f64 + 0.5 - cols as f64 / 2.0) * pitch + offset_u) / DSD
}

fn scan_yaml(cols: usize, pitch: f64, offset_u: f64, views: usize) -> String {
    format!(
        "name: t\ngeometry: {{fan: {{dso: {DSO}, dsd: {DSD}, cols: {cols}, pitch: {pitch}, \
         offset_u: {offset_u}, nx: 32, ny: 32, dx: 1.0, dy: 1.0, detector: curved}}}}\n\
         angles: {{count: {views}}}\nchannels:\n  \
         - {{label: a, coordinate: {{kind: tube_voltage, kvp: 80}}, line_integrals: {{path: p.npy}}}}\n"
    )
}

#[test]
fn a_curved_fan_is_rebinned_exactly_where_the_profile_is_linear_in_the_fan_angle() {
    // p = 0.3 + 0.1·γ + 0.01·view on the arc; linear interpolation in γ reproduces it on the flat
    // line, where column k sits at u_k = dsd·tan γ: p(u_k) = 0.3 + 0.1·atan(u_k/dsd) + 0.01·view,
    // to f32 rounding. Checks the columns' angles, their order and the offset together.
    let dir = tempfile::tempdir().unwrap();
    let (cols, pitch, offset_u) = (161, 1.3, 2.3);
    let p = Array3::from_shape_fn((3, 1, cols), |(v, _, c)| {
        (0.3 + 0.1 * gamma(c, cols, pitch, offset_u) + 0.01 * v as f64) as f32
    });
    ndarray_npy::write_npy(dir.path().join("p.npy"), &p).unwrap();
    let text = scan_yaml(cols, pitch, offset_u, 3);
    let s = assemble(&config(&text), dir.path(), &text).unwrap().scene;
    let d = &s.geometry.detector;
    // The flat line: the arc pitch, spanning the arc's outermost rays (−29.1° to +30.5° here),
    // so more columns than the arc, centred where those rays land.
    let (g0, g1) = (
        gamma(0, cols, pitch, offset_u),
        gamma(cols - 1, cols, pitch, offset_u),
    );
    let (u0, u1) = (DSD * g0.tan(), DSD * g1.tan());
    assert_eq!(d.pitch_u, pitch);
    assert_eq!(d.cols, ((u1 - u0) / pitch).floor() as usize + 1);
    assert!(d.cols > cols);
    assert!((d.offset_u - 0.5 * (u0 + u1)).abs() < 1e-12);
    let mut worst = 0f64;
    for v in 0..3 {
        for k in 0..d.cols {
            let u = (k as f64 + 0.5 - d.cols as f64 / 2.0) * pitch + d.offset_u;
            let want = 0.3 + 0.1 * (u / DSD).atan() + 0.01 * v as f64;
            worst = worst.max((s.projections[[0, v, 0, k]] as f64 - want).abs());
        }
    }
    assert!(worst < 2e-7, "{worst}");
}

/// 2-D Gaussian blobs (centre (x, y) mm, σ mm, peak density mm⁻¹) and their line integral
/// along the line through `src` with unit direction `d`: ρ·σ·√(2π)·exp(−dist²/(2σ²)).
const BLOBS: [([f64; 2], f64, f64); 2] = [([1.0, -2.0], 6.0, 0.02), ([-3.0, 3.0], 2.0, 0.05)];

fn blobs_integral(src: [f64; 2], d: [f64; 2]) -> f64 {
    BLOBS
        .iter()
        .map(|&(c, sigma, rho)| {
            let w = [c[0] - src[0], c[1] - src[1]];
            let t = w[0] * d[0] + w[1] * d[1];
            let dist2 = w[0] * w[0] + w[1] * w[1] - t * t;
            rho * sigma
                * (2.0 * std::f64::consts::PI).sqrt()
                * (-dist2 / (2.0 * sigma * sigma)).exp()
        })
        .sum()
}

#[test]
fn a_curved_fan_scan_becomes_the_flat_lines_line_integrals_within_the_interpolation_bound() {
    // Two Gaussian blobs scanned on an arc (line integrals by hand along the curved rays) and
    // imported as `detector: curved`; every value of the flat scene is compared with the line
    // integral along the flat column's own ray. Linear interpolation errs by at most
    // Δs²·max|p''|/8 (s: arc length at dsd). A blob's profile on the detector is a Gaussian of
    // height A = ρσ√(2π) and width σ_d ≥ σ·dsd/(dso + 6 mm) (no blob lies farther than 6 mm
    // from the axis), so |p''| ≤ Σ A/σ_d², and within ±15° of arc the arc-length curvature adds
    // at most sec⁴15° = 1.15×: the bound below carries 1.5×. A rebinning off by a tenth of a
    // column would err by about Δ/10·max|p'| and break it.
    let angles: Vec<f64> = (0..9)
        .map(|i| i as f64 * 2.0 * std::f64::consts::PI / 9.0)
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let curvature: f64 = BLOBS
        .iter()
        .map(|&(_, sigma, rho)| {
            let sigma_d = sigma * DSD / (DSO + 6.0);
            rho * sigma * (2.0 * std::f64::consts::PI).sqrt() / (sigma_d * sigma_d)
        })
        .sum();
    for (cols, pitch) in [(100usize, 1.0), (200, 0.5)] {
        let offset_u = 0.7;
        let p = Array3::from_shape_fn((angles.len(), 1, cols), |(v, _, c)| {
            let (s, co) = angles[v].sin_cos();
            let (sg, cg) = gamma(c, cols, pitch, offset_u).sin_cos();
            let d = [-cg * co - sg * s, -cg * s + sg * co];
            blobs_integral([DSO * co, DSO * s], d) as f32
        });
        ndarray_npy::write_npy(dir.path().join("p.npy"), &p).unwrap();
        let text = scan_yaml(cols, pitch, offset_u, angles.len());
        let s = assemble(&config(&text), dir.path(), &text).unwrap().scene;
        let det = &s.geometry.detector;
        let mut worst = 0f64;
        for (v, &th) in angles.iter().enumerate() {
            let (sn, co) = th.sin_cos();
            for k in 0..det.cols {
                // The flat column's point: dsd along the central ray, u along the detector.
                let u = (k as f64 + 0.5 - det.cols as f64 / 2.0) * pitch + det.offset_u;
                let d = [-DSD * co - u * sn, -DSD * sn + u * co];
                let len = d[0].hypot(d[1]);
                let want = blobs_integral([DSO * co, DSO * sn], [d[0] / len, d[1] / len]);
                worst = worst.max((s.projections[[0, v, 0, k]] as f64 - want).abs());
            }
        }
        let bound = 1.5 * pitch * pitch / 8.0 * curvature;
        eprintln!("pitch {pitch}: worst {worst:.2e}, bound {bound:.2e}");
        assert!(worst <= bound, "pitch {pitch}: {worst} > {bound}");
    }
}

#[test]
fn a_fan_too_wide_to_rebin_is_refused_naming_the_pitch() {
    // 200 columns of 2 mm at dsd = 200 mm: ±57° of arc is fine; 300 columns (±86°) is not.
    for (cols, ok) in [(200, true), (300, false)] {
        let text = format!(
            "name: t\ngeometry: {{fan: {{dso: 100.0, dsd: 200.0, cols: {cols}, pitch: 2.0, nx: 4, \
             ny: 4, dx: 1.0, dy: 1.0, detector: curved}}}}\nangles: {{count: 4}}\nchannels: []\n"
        );
        let r = config(&text).geometry(Some(vec![0.0]), None);
        match (r, ok) {
            (Ok(_), true) => {}
            (Err(e), false) => {
                let e = e.to_string();
                assert!(e.contains("geometry.fan.pitch") && e.contains("75"), "{e}");
            }
            (r, _) => panic!("{cols} columns: {r:?}"),
        }
    }
}
