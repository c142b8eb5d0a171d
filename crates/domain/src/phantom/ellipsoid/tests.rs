use super::*;
use crate::geometry::{Beam, Detector, Geometry, VolumeGrid};

/// Reference chord without the closed form: along the ray the level function
/// `f(t) = |M(s + t·d − c)|²` is a convex quadratic, so a ternary search finds its minimiser
/// `t_m` on [0, L]; the ray misses when `f(t_m) > 1`. Otherwise the entry and exit are bracketed
/// on [0, t_m] and [t_m, L] and bisected on the membership test `contains` for 200 steps, far
/// past f64 resolution: each end is located to ~1 ulp of t (≈ 2e-13 mm at t ≈ 1000 mm), so the
/// reference is accurate to ≲ 1e-12 mm, well below 1e-6 of any chord tested here (≥ 1e-2 mm).
fn reference_chord(e: &Ellipsoid, s: [f64; 3], d: [f64; 3], l: f64) -> f64 {
    let at = |t: f64| [s[0] + t * d[0], s[1] + t * d[1], s[2] + t * d[2]];
    let (mut lo, mut hi) = (0.0, l);
    for _ in 0..300 {
        let m1 = lo + (hi - lo) / 3.0;
        let m2 = hi - (hi - lo) / 3.0;
        if e.level(at(m1)) < e.level(at(m2)) {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    let tm = 0.5 * (lo + hi);
    if !e.contains(at(tm)) {
        return 0.0;
    }
    // Boundary between an outside point `out` and an inside point `inside`.
    let bisect = |mut out: f64, mut inside: f64| {
        for _ in 0..200 {
            let mid = 0.5 * (out + inside);
            if e.contains(at(mid)) {
                inside = mid;
            } else {
                out = mid;
            }
        }
        0.5 * (out + inside)
    };
    let entry = if e.contains(at(0.0)) {
        0.0
    } else {
        bisect(0.0, tm)
    };
    let exit = if e.contains(at(l)) { l } else { bisect(l, tm) };
    exit - entry
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = dot(v, v).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

fn rotated() -> Vec<Ellipsoid> {
    vec![
        Ellipsoid {
            centre: [12.0, -7.0, 5.0],
            semi_axes: [30.0, 14.0, 22.0],
            rotation_deg: [35.0, 20.0, -50.0],
        },
        Ellipsoid {
            centre: [-20.0, 15.0, -8.0],
            semi_axes: [6.0, 25.0, 10.0],
            rotation_deg: [-110.0, 65.0, 10.0],
        },
        Ellipsoid::sphere([3.0, 4.0, -2.0], 17.0),
    ]
}

#[test]
fn chord_matches_bisection_reference_on_cone_beam_rays() {
    let geometry = Geometry {
        beam: Beam::Cone,
        dso: 500.0,
        dsd: 800.0,
        detector: Detector {
            rows: 32,
            cols: 32,
            pitch_u: 6.0,
            pitch_v: 6.0,
            offset_u: 1.3,
            offset_v: -2.1,
        },
        volume: VolumeGrid::cube(32, 3.0),
        angles_rad: Geometry::uniform_angles(5, 0.3, 6.0),
        vectors: None,
    };
    let mut hits = 0;
    let mut misses = 0;
    for e in rotated() {
        for view in 0..geometry.views() {
            let cam = geometry.camera(view);
            for row in (0..32).step_by(3) {
                for col in (0..32).step_by(3) {
                    let ray = cam.pixel_ray(col as f64, row as f64);
                    let exact = e.ray_chord(&ray);
                    let reference = reference_chord(&e, ray.origin, ray.direction, ray.length);
                    if reference == 0.0 {
                        misses += 1;
                        assert_eq!(exact, 0.0, "miss: {e:?} view {view} ({row}, {col})");
                    } else {
                        hits += 1;
                        let rel = (exact - reference).abs() / reference;
                        assert!(
                            rel <= 1e-6 && reference > 1e-2,
                            "{e:?} view {view} ({row}, {col}): {exact} vs {reference}"
                        );
                    }
                }
            }
        }
    }
    assert!(hits > 100 && misses > 100, "hits {hits}, misses {misses}");
}

#[test]
fn segments_that_start_or_end_inside_and_grazing_rays() {
    let mut checked = 0;
    for e in rotated() {
        let c = e.centre;
        for (k, dir) in [[1.0, 0.3, -0.2], [-0.2, 1.0, 0.5], [0.1, -0.4, 1.0]]
            .into_iter()
            .enumerate()
        {
            let d = unit(dir);
            // Start inside (at the centre), end inside (a short segment), and both outside.
            for (s, l) in [
                (c, 200.0),
                (
                    [c[0] - 40.0 * d[0], c[1] - 40.0 * d[1], c[2] - 40.0 * d[2]],
                    41.5,
                ),
                (
                    [c[0] - 2.0 * d[0], c[1] - 2.0 * d[1], c[2] - 2.0 * d[2]],
                    3.0,
                ),
                (
                    [c[0] - 90.0 * d[0], c[1] - 90.0 * d[1], c[2] - 90.0 * d[2]],
                    180.0,
                ),
            ] {
                let exact = e.chord(s, d, l);
                let reference = reference_chord(&e, s, d, l);
                assert!(
                    (exact - reference).abs() <= 1e-6 * reference,
                    "case {k}: {exact} vs {reference}"
                );
                checked += 1;
            }
        }
    }
    // Grazing: a ray through a sphere at distance r·(1 − ε) from its centre has chord
    // 2r·√(1 − (1 − ε)²); at distance r(1 + ε) it misses.
    let r = 17.0;
    let sphere = Ellipsoid::sphere([3.0, 4.0, -2.0], r);
    for eps in [1e-3, 1e-5, 1e-7] {
        let b = r * (1.0 - eps);
        let s = [3.0 - 500.0, 4.0 + b, -2.0];
        let exact = sphere.chord(s, [1.0, 0.0, 0.0], 1000.0);
        let closed = 2.0 * (r * r - b * b).sqrt();
        assert!(
            (exact - closed).abs() <= 1e-6 * closed,
            "{exact} vs {closed}"
        );
        assert!(
            (exact - reference_chord(&sphere, s, [1.0, 0.0, 0.0], 1000.0)).abs() <= 1e-6 * closed
        );
        let miss = [3.0 - 500.0, 4.0 + r * (1.0 + eps), -2.0];
        assert_eq!(sphere.chord(miss, [1.0, 0.0, 0.0], 1000.0), 0.0);
    }
    assert_eq!(checked, 36);
}

#[test]
fn sphere_through_centre_and_clipped_segments() {
    let r = 12.5;
    let s = Ellipsoid::sphere([1.0, -2.0, 3.0], r);
    let d = unit([0.3, -0.5, 0.8]);
    let start = [1.0 - 100.0 * d[0], -2.0 - 100.0 * d[1], 3.0 - 100.0 * d[2]];
    assert!((s.chord(start, d, 300.0) - 2.0 * r).abs() <= 1e-12 * r);
    // Segment ends at the centre: half the chord. Starts at the centre: the other half.
    assert!((s.chord(start, d, 100.0) - r).abs() <= 1e-12 * r);
    let centre = [1.0, -2.0, 3.0];
    assert!((s.chord(centre, d, 50.0) - r).abs() <= 1e-12 * r);
    // Segment entirely inside: its own length.
    assert!((s.chord(centre, d, 4.0) - 4.0).abs() <= 1e-12);
    // Segment ends before the sphere, or starts after it: zero.
    assert_eq!(s.chord(start, d, 80.0), 0.0);
    assert_eq!(
        s.chord(
            [1.0 + 20.0 * d[0], -2.0 + 20.0 * d[1], 3.0 + 20.0 * d[2]],
            d,
            50.0
        ),
        0.0
    );
    // Degenerate segments.
    assert_eq!(s.chord(centre, d, 0.0), 0.0);
    assert_eq!(s.chord(centre, d, f64::NAN), 0.0);
}

#[test]
fn rotation_about_z_turns_the_body_axes_counter_clockwise() {
    // φ about z: the chord along world x through the centre is 2/√(cos²φ/a² + sin²φ/b²).
    let (a, b) = (20.0, 8.0);
    for phi in [0.0f64, 30.0, 90.0, 135.0] {
        let e = Ellipsoid {
            centre: [5.0, -3.0, 2.0],
            semi_axes: [a, b, 4.0],
            rotation_deg: [phi, 0.0, 0.0],
        };
        let (s, c) = phi.to_radians().sin_cos();
        let expected = 2.0 / ((c / a).powi(2) + (s / b).powi(2)).sqrt();
        let chord = e.chord([-100.0, -3.0, 2.0], [1.0, 0.0, 0.0], 300.0);
        assert!((chord - expected).abs() <= 1e-12 * expected, "φ = {phi}");
    }
    // φ = 90°: the long body axis (x) now points along +y.
    let e = Ellipsoid {
        centre: [0.0; 3],
        semi_axes: [a, b, 4.0],
        rotation_deg: [90.0, 0.0, 0.0],
    };
    assert!(e.contains([0.0, 0.99 * a, 0.0]) && !e.contains([0.99 * a, 0.0, 0.0]));
    // θ = 90° about y maps the body z axis onto world x.
    let e = Ellipsoid {
        centre: [0.0; 3],
        semi_axes: [2.0, 3.0, 15.0],
        rotation_deg: [0.0, 90.0, 0.0],
    };
    assert!(e.contains([14.9, 0.0, 0.0]) && !e.contains([0.0, 0.0, 14.9]));
}

#[test]
fn bounding_box_encloses_surface_and_is_tight() {
    for e in rotated() {
        let (lo, hi) = e.bounding_box();
        let r = e.rotation();
        let mut reached_lo = [f64::INFINITY; 3];
        let mut reached_hi = [f64::NEG_INFINITY; 3];
        for i in 0..200 {
            for j in 0..100 {
                let (u, v) = (
                    i as f64 / 200.0 * std::f64::consts::TAU,
                    j as f64 / 99.0 * std::f64::consts::PI,
                );
                let q = [
                    e.semi_axes[0] * v.sin() * u.cos(),
                    e.semi_axes[1] * v.sin() * u.sin(),
                    e.semi_axes[2] * v.cos(),
                ];
                for k in 0..3 {
                    let p = e.centre[k] + r[k][0] * q[0] + r[k][1] * q[1] + r[k][2] * q[2];
                    assert!(p >= lo[k] - 1e-9 && p <= hi[k] + 1e-9);
                    reached_lo[k] = reached_lo[k].min(p);
                    reached_hi[k] = reached_hi[k].max(p);
                }
            }
        }
        for k in 0..3 {
            let span = hi[k] - lo[k];
            assert!(reached_lo[k] - lo[k] < 0.01 * span && hi[k] - reached_hi[k] < 0.01 * span);
        }
    }
}

#[test]
fn validation_names_the_field_and_serde_round_trips() {
    let mut e = Ellipsoid::sphere([0.0; 3], 1.0);
    e.semi_axes[1] = 0.0;
    assert!(
        e.validate()
            .unwrap_err()
            .to_string()
            .contains("semi_axes[1]")
    );
    e.semi_axes[1] = 1.0;
    e.centre[2] = f64::NAN;
    assert!(e.validate().unwrap_err().to_string().contains("centre[2]"));
    let yaml = "centre: [1, 2, 3]\nsemi_axes: [4, 5, 6]\nrotation_deg: [10, 0, 0]\n";
    let e: Ellipsoid = serde_yaml_ng::from_str(yaml).unwrap();
    assert_eq!(e.rotation_deg, [10.0, 0.0, 0.0]);
    let back: Ellipsoid = serde_json::from_str(&serde_json::to_string(&e).unwrap()).unwrap();
    assert_eq!(back, e);
}
