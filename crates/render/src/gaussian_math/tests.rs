//! Checks of the shared math against independent truth: closed forms, quadrature and f64 central
//! differences.

use super::*;
use crate::camera::{Camera, Projection};

/// θ = 0 view of a 32² detector: source at +x·500, detector 800 from the source.
pub(crate) fn cone_camera(rows: usize, cols: usize) -> Camera {
    Camera {
        projection: Projection::Cone,
        rotation: [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]],
        translation: [0.0, 0.0, 500.0],
        fx: 800.0 / 2.0,
        fy: 800.0 / 2.5,
        cx: (cols as f64 - 1.0) / 2.0 + 0.3,
        cy: (rows as f64 - 1.0) / 2.0 - 0.2,
        rows,
        cols,
        sdd: 800.0,
    }
}

/// An oblique parallel view (θ = 0.7): pixels per mm 1/1.5 and 1/2.
pub(crate) fn parallel_camera(rows: usize, cols: usize) -> Camera {
    let (s, c) = 0.7f64.sin_cos();
    Camera {
        projection: Projection::Parallel,
        rotation: [[-s, c, 0.0], [0.0, 0.0, -1.0], [-c, -s, 0.0]],
        translation: [0.0, 0.0, 500.0],
        fx: 1.0 / 1.5,
        fy: 1.0 / 2.0,
        cx: (cols as f64 - 1.0) / 2.0,
        cy: (rows as f64 - 1.0) / 2.0,
        rows,
        cols,
        sdd: 800.0,
    }
}

pub(crate) fn aniso() -> GaussianGeom {
    GaussianGeom {
        mean: [3.0, -2.0, 4.0],
        scale: [2.0, 5.0, 3.5],
        quat: [0.8, 0.3, -0.5, 0.2],
    }
}

fn rel(a: f64, b: f64, scale: f64) -> f64 {
    (a - b).abs() / scale.max(f64::MIN_POSITIVE)
}

/// Adaptive Simpson quadrature (f64) — independent of the closed form.
fn simpson(f: &dyn Fn(f64) -> f64, a: f64, b: f64, tol: f64, depth: u32) -> f64 {
    /// One panel of the recursion: the interval `[a, b]`, `f` at its ends and midpoint
    /// (`fa`, `fb`, `fm`), and the panel's Simpson estimate `whole`.
    #[derive(Clone, Copy)]
    struct Panel {
        a: f64,
        b: f64,
        fa: f64,
        fm: f64,
        fb: f64,
        whole: f64,
    }
    fn rec(f: &dyn Fn(f64) -> f64, p: Panel, tol: f64, d: u32) -> f64 {
        let Panel {
            a,
            b,
            fa,
            fm,
            fb,
            whole,
        } = p;
        let m = 0.5 * (a + b);
        let (lm, rm) = (0.5 * (a + m), 0.5 * (m + b));
        let (flm, frm) = (f(lm), f(rm));
        let left = (m - a) / 6.0 * (fa + 4.0 * flm + fm);
        let right = (b - m) / 6.0 * (fm + 4.0 * frm + fb);
        if d == 0 || (left + right - whole).abs() <= 15.0 * tol {
            return left + right + (left + right - whole) / 15.0;
        }
        let left = Panel {
            a,
            b: m,
            fa,
            fm: flm,
            fb: fm,
            whole: left,
        };
        let right = Panel {
            a: m,
            b,
            fa: fm,
            fm: frm,
            fb,
            whole: right,
        };
        rec(f, left, tol / 2.0, d - 1) + rec(f, right, tol / 2.0, d - 1)
    }
    let (fa, fb, fm) = (f(a), f(b), f(0.5 * (a + b)));
    let whole = (b - a) / 6.0 * (fa + 4.0 * fm + fb);
    let panel = Panel {
        a,
        b,
        fa,
        fm,
        fb,
        whole,
    };
    rec(f, panel, tol, depth)
}

/// Direct evaluation of the unit-density Gaussian at a world point.
fn density_at(g: &GaussianGeom, x: V3) -> f64 {
    let sh = shape3(g).unwrap();
    let d = [x[0] - g.mean[0], x[1] - g.mean[1], x[2] - g.mean[2]];
    (-0.5 * dot(d, mat_vec(&sh.prec, d))).exp()
}

#[test]
fn mu_matches_the_determinant_ratio_form() {
    // μ = √(2π det Σ_ray / det Σ_2D) with the extended Jacobian [J; r̂ᵀ] (R²-Gaussian's form).
    let cam = cone_camera(32, 32);
    let g = aniso();
    let s = splat(&g, &cam, [0.0; 2], 3.0, 1e-3).unwrap();
    let sh = shape3(&g).unwrap();
    let t = cam.to_camera(g.mean);
    let cov_c = congruence(&cam.rotation, &sh.cov);
    let l = dot(t, t).sqrt();
    let j: M3 = [
        [cam.fx / t[2], 0.0, -cam.fx * t[0] / (t[2] * t[2])],
        [0.0, cam.fy / t[2], -cam.fy * t[1] / (t[2] * t[2])],
        [t[0] / l, t[1] / l, t[2] / l],
    ];
    let ray = congruence(&j, &cov_c);
    let det3 = ray[0][0] * (ray[1][1] * ray[2][2] - ray[1][2] * ray[2][1])
        - ray[0][1] * (ray[1][0] * ray[2][2] - ray[1][2] * ray[2][0])
        + ray[0][2] * (ray[1][0] * ray[2][1] - ray[1][1] * ray[2][0]);
    let det2 = ray[0][0] * ray[1][1] - ray[0][1] * ray[1][0];
    let mu_det = (2.0 * std::f64::consts::PI * det3 / det2).sqrt();
    assert!(rel(s.mu, mu_det, mu_det) < 1e-12, "{} vs {}", s.mu, mu_det);
    // And μ is the exact line integral along the ray through the centre.
    let dir = [t[0] / l, t[1] / l, t[2] / l];
    let rg = RayGaussian {
        centre: t,
        prec: congruence(&cam.rotation, &sh.prec),
    };
    let through = line_integral(&rg, [0.0; 3], dir, 1e6);
    // The ray form evaluates the Mahalanobis distance of a point 500 mm out: ~1e-12 rounding.
    assert!(rel(s.mu, through, s.mu) < 1e-10, "{} vs {through}", s.mu);
}

#[test]
fn isotropic_central_ray_is_sqrt_2pi_sigma() {
    for cam in [cone_camera(32, 32), parallel_camera(32, 32)] {
        let g = GaussianGeom {
            mean: [0.0; 3],
            scale: [4.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
        };
        let s = splat(&g, &cam, [0.0; 2], 3.0, 1e-3).unwrap();
        assert!(rel(s.mu, SQRT_2PI * 4.0, SQRT_2PI * 4.0) < 1e-14);
    }
}

#[test]
fn exact_line_integral_matches_quadrature() {
    // Segments through, beside, and truncated by the ends of the ray (Gaussian at the source and
    // at the detector plane), anisotropic and rotated.
    let cam = cone_camera(32, 32);
    let sh_world = aniso();
    let mut worst = 0.0f64;
    for (mean, pix) in [
        ([3.0, -2.0, 4.0], (15.0, 16.0)),
        ([3.0, -2.0, 4.0], (22.0, 9.0)),
        ([496.0, 0.5, 0.0], (16.0, 15.0)), // 4 mm in front of the source: crosses z_c = 0
        ([-299.0, 1.0, -2.0], (15.5, 15.2)), // straddles the detector plane
    ] {
        let g = GaussianGeom { mean, ..sh_world };
        let sh = shape3(&g).unwrap();
        let rg = RayGaussian {
            centre: cam.to_camera(g.mean),
            prec: congruence(&cam.rotation, &sh.prec),
        };
        let (o, d, len) = camera_ray(&cam, pix.0, pix.1);
        let closed = line_integral(&rg, o, d, len);
        // Quadrature of the world-space density along the world ray.
        let ray = cam.pixel_ray(pix.0, pix.1);
        let f = |t: f64| {
            density_at(
                &g,
                [
                    ray.origin[0] + t * ray.direction[0],
                    ray.origin[1] + t * ray.direction[1],
                    ray.origin[2] + t * ray.direction[2],
                ],
            )
        };
        // 4000 panels of adaptive Simpson: the Gaussian (σ ≥ 2 mm along any ray) spans many
        // panels, so no panel's initial samples can miss it.
        let panels = 4000;
        let w = ray.length / panels as f64;
        let quad: f64 = (0..panels)
            .map(|i| simpson(&f, i as f64 * w, (i + 1) as f64 * w, 1e-16, 30))
            .sum();
        let peak = SQRT_2PI * 5.0;
        worst = worst.max(rel(closed, quad, peak));
        assert!(
            rel(closed, quad, peak) < 1e-6,
            "{mean:?}: {closed} vs {quad}"
        );
        assert!(closed > 0.0);
    }
    eprintln!("exact vs quadrature: max error / peak = {worst:.2e}");
}

/// Central differences of a scalar function of a parameter vector.
fn fd(f: &dyn Fn(&[f64]) -> f64, x: &[f64], h: f64) -> Vec<f64> {
    (0..x.len())
        .map(|i| {
            let mut p = x.to_vec();
            let mut m = x.to_vec();
            p[i] += h;
            m[i] -= h;
            (f(&p) - f(&m)) / (2.0 * h)
        })
        .collect()
}

fn unpack(x: &[f64]) -> GaussianGeom {
    GaussianGeom {
        mean: [x[0], x[1], x[2]],
        scale: [x[3], x[4], x[5]],
        quat: [x[6], x[7], x[8], x[9]],
    }
}

fn pack(g: &GeomGrad) -> Vec<f64> {
    g.mean
        .iter()
        .chain(&g.scale)
        .chain(&g.quat)
        .copied()
        .collect()
}

fn assert_grad_close(analytic: &[f64], numeric: &[f64], tol: f64, what: &str) {
    let scale = numeric.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, (a, n)) in analytic.iter().zip(numeric).enumerate() {
        assert!(
            (a - n).abs() <= tol * scale,
            "{what}[{i}]: analytic {a} vs numeric {n} (scale {scale})"
        );
    }
}

#[test]
fn splat_backward_matches_central_differences() {
    // L = wm·mean + wc·conic + wμ·μ for fixed random-ish weights; f64 throughout, h = 1e-6 gives
    // truncation O(h²·f''') ≈ 1e-12 and rounding ≈ 1e-16/h = 1e-10 relative: tolerance 1e-6.
    let weights = SplatGrad {
        mean: [0.7, -1.3],
        conic: [2.0, -0.6, 1.1],
        mu: 0.9,
    };
    for cam in [cone_camera(32, 32), parallel_camera(32, 32)] {
        for off in [[0.0, 0.0], [0.4, -0.25]] {
            let g0 = aniso();
            let x0: Vec<f64> = g0
                .mean
                .iter()
                .chain(&g0.scale)
                .chain(&g0.quat)
                .copied()
                .collect();
            let loss = |x: &[f64]| {
                let s = splat(&unpack(x), &cam, off, 3.0, 1e-3).unwrap();
                let w = &weights;
                w.mean[0] * s.mean[0]
                    + w.mean[1] * s.mean[1]
                    + w.conic[0] * s.conic_mat[0]
                    + 2.0 * w.conic[1] * s.conic_mat[1]
                    + w.conic[2] * s.conic_mat[2]
                    + w.mu * s.mu
            };
            // The off-diagonal conic entry appears twice in the full-matrix convention.
            let g = splat_backward(&g0, &cam, off, 3.0, 1e-3, &weights);
            assert_grad_close(&pack(&g), &fd(&loss, &x0, 1e-6), 1e-6, "splat");
        }
    }
}

#[test]
fn line_integral_backward_matches_central_differences() {
    let cam = cone_camera(32, 32);
    let g0 = GaussianGeom {
        mean: [480.0, 2.0, -1.0],
        ..aniso()
    }; // near the source: erf terms active
    for pix in [(15.0, 16.0), (20.0, 11.0)] {
        let (o, d, len) = camera_ray(&cam, pix.0, pix.1);
        let prep = |g: &GaussianGeom| {
            let sh = shape3(g).unwrap();
            RayGaussian {
                centre: cam.to_camera(g.mean),
                prec: congruence(&cam.rotation, &sh.prec),
            }
        };
        let rg = prep(&g0);
        let (_, gc, gp) = line_integral_backward(&rg, o, d, len, 1.0);
        let x0: Vec<f64> = g0
            .mean
            .iter()
            .chain(&g0.scale)
            .chain(&g0.quat)
            .copied()
            .collect();
        let loss = |x: &[f64]| line_integral(&prep(&unpack(x)), o, d, len);
        let (geo, _) = exact_splat_backward(&g0, &cam, [0.0; 2], gc, &gp);
        // h = 1e-4: truncation O(h²) ≈ 1e-8 relative, rounding ≈ 1e-14/h = 1e-10.
        assert_grad_close(&pack(&geo), &fd(&loss, &x0, 1e-4), 1e-6, "exact");
    }
}

#[test]
fn exact_screen_offset_gradient_matches_central_differences() {
    let cam = cone_camera(32, 32);
    let g0 = aniso();
    let (o, d, len) = camera_ray(&cam, 17.0, 14.0);
    let off0 = [0.3, -0.2];
    let value = |off: [f64; 2], g: &GaussianGeom| {
        let s = exact_splat(g, &cam, off, 50.0).unwrap();
        line_integral(&s.ray_gaussian, o, d, len)
    };
    let s = exact_splat(&g0, &cam, off0, 50.0).unwrap();
    let (_, gc, gp) = line_integral_backward(&s.ray_gaussian, o, d, len, 1.0);
    let (geo, gs) = exact_splat_backward(&g0, &cam, off0, gc, &gp);
    let h = 1e-4;
    let num_s: Vec<f64> = (0..2)
        .map(|a| {
            let (mut p, mut m) = (off0, off0);
            p[a] += h;
            m[a] -= h;
            (value(p, &g0) - value(m, &g0)) / (2.0 * h)
        })
        .collect();
    assert_grad_close(&gs, &num_s, 1e-6, "screen");
    let x0: Vec<f64> = g0
        .mean
        .iter()
        .chain(&g0.scale)
        .chain(&g0.quat)
        .copied()
        .collect();
    let loss = |x: &[f64]| value(off0, &unpack(x));
    assert_grad_close(&pack(&geo), &fd(&loss, &x0, 1e-4), 1e-6, "exact+offset");
}

#[test]
fn voxel_backward_matches_central_differences() {
    let g0 = aniso();
    let pts: [V3; 3] = [[4.0, -1.0, 5.0], [1.0, -4.0, 2.5], [6.0, 0.0, 3.0]];
    let wts = [0.8, -1.5, 0.6];
    let loss = |x: &[f64]| -> f64 {
        let g = unpack(x);
        pts.iter()
            .zip(wts)
            .map(|(p, w)| w * density_at(&g, *p))
            .sum()
    };
    let sh = shape3(&g0).unwrap();
    let mut sum_d = [0.0; 3];
    let mut sum_dd = [[0.0; 3]; 3];
    for (p, w) in pts.iter().zip(wts) {
        let d = [p[0] - g0.mean[0], p[1] - g0.mean[1], p[2] - g0.mean[2]];
        let e = (-0.5 * dot(d, mat_vec(&sh.prec, d))).exp();
        for i in 0..3 {
            sum_d[i] += w * e * d[i];
            for j in 0..3 {
                sum_dd[i][j] += w * e * d[i] * d[j];
            }
        }
    }
    let x0: Vec<f64> = g0
        .mean
        .iter()
        .chain(&g0.scale)
        .chain(&g0.quat)
        .copied()
        .collect();
    assert_grad_close(
        &pack(&voxel_backward(&g0, sum_d, &sum_dd)),
        &fd(&loss, &x0, 1e-6),
        1e-6,
        "voxel",
    );
}

#[test]
fn factored_quadratic_forms_match_the_matrix_and_survive_needles() {
    // Scale ratio 1e4 rotated: the factored form stays within rounding of the f64 matrix form.
    let g = GaussianGeom {
        mean: [0.0; 3],
        scale: [1e-2, 1e2, 1.0],
        quat: [0.9, 0.1, 0.3, -0.2],
    };
    let sh = shape3(&g).unwrap();
    let q = Quad3::new(&sh.prec).unwrap();
    for d in [[0.3, -20.0, 1.0], [1e-3, 5.0, 0.02], [0.0, 0.0, 0.5]] {
        let direct = dot(d, mat_vec(&sh.prec, d));
        assert!(rel(q.eval(d), direct, direct.max(1.0)) < 1e-8, "{d:?}");
    }
    let c = [[4.0, 1.0], [1.0, 3.0]];
    let q2 = Quad2::new(c).unwrap();
    let (dx, dy) = (0.7, -1.2);
    let direct = 4.0 * dx * dx + 2.0 * dx * dy + 3.0 * dy * dy;
    assert!(rel(q2.eval(dx, dy), direct, direct) < 1e-14);
    assert!(Quad2::new([[1.0, 2.0], [2.0, 1.0]]).is_none());
}

/// Gaussians every function must reject: zero quaternion, zero, negative and infinite scales,
/// a NaN mean, and (cone beam) a centre behind the source.
fn degenerate_gaussians() -> [GaussianGeom; 6] {
    [
        GaussianGeom {
            quat: [0.0; 4],
            ..aniso()
        },
        GaussianGeom {
            scale: [0.0, 1.0, 1.0],
            ..aniso()
        },
        GaussianGeom {
            scale: [-1.0, 1.0, 1.0],
            ..aniso()
        },
        GaussianGeom {
            mean: [f64::NAN, 0.0, 0.0],
            ..aniso()
        },
        GaussianGeom {
            scale: [f64::INFINITY, 1.0, 1.0],
            ..aniso()
        },
        GaussianGeom {
            mean: [600.0, 0.0, 0.0],
            ..aniso()
        },
    ]
}

#[test]
fn degenerate_gaussians_are_rejected() {
    let cam = cone_camera(8, 8);
    let bad = degenerate_gaussians();
    for g in bad {
        assert!(splat(&g, &cam, [0.0; 2], 3.0, 1e-3).is_none(), "{g:?}");
        let gg = splat_backward(
            &g,
            &cam,
            [0.0; 2],
            3.0,
            1e-3,
            &SplatGrad {
                mean: [1.0; 2],
                conic: [1.0; 3],
                mu: 1.0,
            },
        );
        assert_eq!(gg, GeomGrad::default());
    }
}

#[test]
fn lanes_compute_each_gaussian_bit_for_bit_as_alone() {
    // Four Gaussians in F64x4 lanes run the scalar operations lane by lane: every value of the
    // splat and of its chain rule equals, to the bit, the one-Gaussian result, and a degenerate
    // (or behind-the-source) lane is flagged without touching its neighbours.
    let good = |j: usize| GaussianGeom {
        mean: [3.0 - j as f64, -2.0 + 0.7 * j as f64, 4.0 + 0.3 * j as f64],
        scale: [2.0 + 0.5 * j as f64, 5.0, 3.5 - 0.4 * j as f64],
        quat: [0.8, 0.3 + 0.1 * j as f64, -0.5, 0.2],
    };
    let bad = degenerate_gaussians();
    let offsets = |j: usize| [0.25 * j as f64, -0.1];
    let image_grad = |sp: &Splat| SplatGrad {
        mean: [0.3 * sp.mu, -0.2],
        conic: [sp.conic_mat[0], -0.5, 0.7 * sp.mu],
        mu: 1.3,
    };
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for cam in [cone_camera(32, 32), parallel_camera(32, 32)] {
        for (slot, b) in bad.iter().enumerate() {
            let slot = slot % F64_LANES;
            let geoms: [GaussianGeom; F64_LANES] =
                std::array::from_fn(|j| if j == slot { *b } else { good(j) });
            let lanes = GaussianGeom::lanes(|j| geoms[j]);
            let off = F64x4::gather(offsets);
            let (sp, ok) = splat_masked(&lanes, &cam, off, 3.0, 1e-3);
            let lane_grad = |sp: &Splat<F64x4>| {
                let g: [SplatGrad; F64_LANES] = std::array::from_fn(|j| image_grad(&sp.lane(j)));
                SplatGrad {
                    mean: F64x4::gather(|j| g[j].mean),
                    conic: F64x4::gather(|j| g[j].conic),
                    mu: F64x4::from_fn(|j| g[j].mu),
                }
            };
            let (geo, _, ok_back) = splat_backward_masked(&lanes, &cam, off, 3.0, 1e-3, lane_grad);
            assert_eq!(ok, ok_back);
            for (j, g) in geoms.iter().enumerate() {
                let alone = splat(g, &cam, offsets(j), 3.0, 1e-3);
                assert_eq!(ok.lane(j), alone.is_some(), "lane {j}, bad slot {slot}");
                let Some(alone) = alone else { continue };
                let lane = sp.lane(j);
                let flat = |s: &Splat| {
                    let q = s.conic;
                    let mut v = vec![s.mu, q.a, q.beta, q.gamma];
                    v.extend(s.mean.iter().chain(&s.conic_mat).chain(&s.half_extent));
                    v
                };
                assert_eq!(bits(&flat(&lane)), bits(&flat(&alone)), "splat, lane {j}");
                let (want, _) =
                    splat_backward_with(g, &cam, offsets(j), 3.0, 1e-3, image_grad).unwrap();
                assert_eq!(
                    bits(&pack(&geo.lane(j))),
                    bits(&pack(&want)),
                    "chain, lane {j}"
                );
            }
        }
    }
}
