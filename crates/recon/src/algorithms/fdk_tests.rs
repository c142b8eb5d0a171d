use super::*;
use prism_domain::geometry::Beam;
use prism_domain::testing::{Ellipsoid, analytic_projections, geometry};

/// Mean of the reconstruction over voxels well inside a sphere of radius `r` at the origin.
fn interior_mean(g: &Geometry, vol: &Array3<f32>, r: f64) -> f64 {
    let v = &g.volume;
    let (mut s, mut n) = (0.0, 0);
    for ((iz, iy, ix), x) in vol.indexed_iter() {
        let p = v.voxel_centre(ix, iy, iz);
        if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() < 0.6 * r {
            s += *x as f64;
            n += 1;
        }
    }
    s / n as f64
}

fn sphere(r: f64) -> Vec<Ellipsoid> {
    vec![Ellipsoid {
        centre: [0.0; 3],
        axes: [r; 3],
        rho: 0.02,
    }]
}

#[test]
fn full_scan_reproduces_density_cone_and_parallel() {
    // With dense views FDK is exact in the mid-plane and nearly so at small cone angles for a
    // sphere; the interior mean matches ρ to discretisation error (< 2 % here). A scaling error
    // (missing ½, 2π, pitch or magnification) would be off by ≥ 30 %.
    for beam in [Beam::Cone, Beam::Parallel] {
        for window in [Window::RamLak, Window::Hann] {
            let mut g = geometry(beam, 24, 40, 90, true);
            g.volume.offset = [0.0; 3];
            let objs = sphere(9.0);
            let p = analytic_projections(&g, &objs);
            let vol = fdk(&g, p.view(), window).unwrap();
            let m = interior_mean(&g, &vol, 9.0);
            assert!((m / 0.02 - 1.0).abs() < 0.02, "{beam:?} {window:?}: {m}");
            // Outside the object the reconstruction is near 0.
            assert!(vol[[1, 1, 1]].abs() < 0.002, "{}", vol[[1, 1, 1]]);
        }
    }
}

#[test]
fn short_scan_with_parker_weights_reproduces_density() {
    let mut g = geometry(Beam::Cone, 24, 40, 90, false);
    let fan = ((g.detector.cols as f64 * g.detector.pitch_u / 2.0) / g.dsd).atan();
    let range = PI + 2.0 * fan + 0.05;
    g.angles_rad = Geometry::uniform_angles(90, 0.3, range * 90.0 / 89.0);
    assert_eq!(scan_kind(&g), ScanKind::Short);
    let objs = sphere(9.0);
    let p = analytic_projections(&g, &objs);
    let vol = fdk(&g, p.view(), Window::RamLak).unwrap();
    let m = interior_mean(&g, &vol, 9.0);
    assert!((m / 0.02 - 1.0).abs() < 0.03, "{m}");
}

#[test]
fn parker_weights_of_conjugate_rays_sum_to_one() {
    // Build the conjugate of each ray geometrically from the cameras (the ray through source
    // S(β₁) and pixel u₁ is measured again from the other source position on the same line),
    // independent of the closed-form conjugate used in `Parker::weight`.
    let mut g = geometry(Beam::Cone, 24, 40, 3, false);
    let delta = 0.25;
    g.angles_rad = vec![0.0, PI + 2.0 * delta];
    assert!(Parker::new(&g).is_ok());
    for b1 in [0.05, 0.3, 0.7, 1.4, 2.2, 3.0] {
        for u1 in [-25.0, -12.0, -3.0, 0.0, 4.0, 10.0, 22.0] {
            let th1: f64 = b1;
            let s1 = [g.dso * th1.cos(), g.dso * th1.sin()];
            let eu = [-th1.sin(), th1.cos()];
            let dir = [
                -g.dsd * th1.cos() + u1 * eu[0],
                -g.dsd * th1.sin() + u1 * eu[1],
            ];
            // Other intersection of the line s1 + t·dir with the circle of radius DSO.
            let t = -2.0 * (s1[0] * dir[0] + s1[1] * dir[1]) / (dir[0] * dir[0] + dir[1] * dir[1]);
            let s2 = [s1[0] + t * dir[0], s1[1] + t * dir[1]];
            let th2 = s2[1].atan2(s2[0]).rem_euclid(2.0 * PI);
            // Column of S(β₁) seen from S(β₂).
            let cam2 = g.camera_at(th2);
            let c = cam2.project([s1[0], s1[1], 0.0]).unwrap()[0];
            let u2 = (c - cam2.cx) * g.detector.pitch_u;
            let w1 = parker_weight(b1, -(u1 / g.dsd).atan(), delta);
            let w2 = parker_weight(th2, -(u2 / g.dsd).atan(), delta);
            assert!(
                (w1 + w2 - 1.0).abs() < 1e-9,
                "β {b1} u {u1}: {w1} + {w2} (β₂ {th2})"
            );
        }
    }
}

#[test]
fn sparse_full_turns_are_not_short_scans() {
    for n in [3, 10, 25, 50, 360] {
        let g = geometry(Beam::Cone, 8, 8, n, false);
        assert_eq!(scan_kind(&g), ScanKind::Full, "{n}");
    }
    let mut g = geometry(Beam::Cone, 8, 8, 100, false);
    g.angles_rad = Geometry::uniform_angles(100, 0.0, 200f64.to_radians());
    assert_eq!(scan_kind(&g), ScanKind::Short);
    let w = angular_weights(&geometry(Beam::Cone, 8, 8, 50, false), ScanKind::Full);
    assert!(w.iter().all(|x| (x - 2.0 * PI / 50.0).abs() < 1e-12));
}

#[test]
fn bad_inputs_are_errors() {
    let g = geometry(Beam::Cone, 8, 8, 4, false);
    let p = Array3::<f32>::zeros((3, 8, 8));
    assert!(
        fdk(&g, p.view(), Window::RamLak)
            .unwrap_err()
            .to_string()
            .contains("projections")
    );
    let mut short = g.clone();
    short.angles_rad = vec![0.0, 0.5, 1.0, 1.5];
    let p = Array3::<f32>::zeros((4, 8, 8));
    let e = fdk(&short, p.view(), Window::RamLak)
        .unwrap_err()
        .to_string();
    assert!(e.contains("angles_rad") && e.contains("short scan"), "{e}");
}

#[test]
fn per_view_vectors_are_followed() {
    use prism_domain::testing::{phantom, rel_l2, voxelise, wobbled};
    for beam in [Beam::Cone, Beam::Parallel] {
        let mut g = geometry(beam, 24, 40, 90, true);
        g.volume.offset = [0.0; 3];
        let objs = phantom(9.0);
        // A circular scan given as vectors is the same scan: equal to rounding (the cosine
        // weights and τ computed from each camera instead of the shared fields).
        let p = analytic_projections(&g, &objs);
        let circular = fdk(&g, p.view(), Window::RamLak).unwrap();
        let held = Geometry {
            vectors: Some(g.to_vectors()),
            ..g.clone()
        };
        let same = fdk(&held, p.view(), Window::RamLak).unwrap();
        let diff = rel_l2(&same, &circular);
        assert!(diff < 1e-5, "{beam:?}: {diff:e}");
        // A disturbed scan: reconstructed with its vectors, against its data read as the
        // nominal circular scan (the wobble, spin, tilt and shifts ignored).
        let w = wobbled(&g);
        let p = analytic_projections(&w, &objs);
        let truth = voxelise(&w.volume, &objs, 2);
        let followed = rel_l2(&fdk(&w, p.view(), Window::RamLak).unwrap(), &truth);
        let nominal = Geometry {
            vectors: None,
            ..w.clone()
        };
        let ignored = rel_l2(&fdk(&nominal, p.view(), Window::RamLak).unwrap(), &truth);
        eprintln!("{beam:?}: FDK error with the vectors {followed:.4}, ignoring them {ignored:.4}");
        assert!(
            followed < 0.5 * ignored,
            "{beam:?}: {followed} vs {ignored}"
        );
    }
}
