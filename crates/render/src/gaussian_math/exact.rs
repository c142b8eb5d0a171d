//! The exact line integral of a Gaussian along a ray (closed form, no cone-beam
//! approximation), per pixel, and its backward pass.

use super::*;

/// A Gaussian prepared for exact ray integrals in one view (camera frame).
#[derive(Clone, Copy, Debug)]
pub struct RayGaussian {
    /// Centre in camera coordinates.
    pub centre: V3,
    /// Camera-frame precision `Σ_c⁻¹`.
    pub prec: M3,
}

/// Camera-frame ray through pixel (column, row): origin, unit direction, length.
#[inline]
pub fn camera_ray(cam: &Camera, col: f64, row: f64) -> (V3, V3, f64) {
    let end = cam.pixel_camera(col, row);
    match cam.projection {
        Projection::Cone => {
            let len = dot(end, end).sqrt();
            ([0.0; 3], [end[0] / len, end[1] / len, end[2] / len], len)
        }
        Projection::Parallel => ([end[0], end[1], 0.0], [0.0, 0.0, 1.0], cam.sdd),
    }
}

/// The ray quantities of the exact integral: `a = dᵀPd`, `b = dᵀPm`, `c = mᵀPm`, `m = o − p`.
#[derive(Clone, Copy, Debug)]
pub struct RayTerms {
    pub a: f64,
    pub b: f64,
    pub c: f64,
    /// Squared Mahalanobis distance from the centre to the (infinite) ray line, `c − b²/a ≥ 0`.
    pub q: f64,
}

#[inline]
pub fn ray_terms(rg: &RayGaussian, origin: V3, dir: V3) -> Option<RayTerms> {
    let m = [
        origin[0] - rg.centre[0],
        origin[1] - rg.centre[1],
        origin[2] - rg.centre[2],
    ];
    let pd = mat_vec(&rg.prec, dir);
    let pm = mat_vec(&rg.prec, m);
    let a = dot(dir, pd);
    let b = dot(dir, pm);
    let c = dot(m, pm);
    if !(a > 0.0 && a.is_finite() && b.is_finite() && c.is_finite()) {
        return None;
    }
    // q = c − b²/a cancels badly when the centre is many σ from the origin; evaluate it as the
    // quadratic form at the closest point instead: v = m + t*·d, t* = −b/a.
    let ts = -b / a;
    let v = [m[0] + ts * dir[0], m[1] + ts * dir[1], m[2] + ts * dir[2]];
    let q = dot(v, mat_vec(&rg.prec, v)).max(0.0);
    Some(RayTerms { a, b, c, q })
}

/// `∫₀ᴸ exp(−½ q(t)) dt` for the segment: `√(2π/a) · e^{−q/2} · ½[erf(u₁) − erf(u₀)]` with
/// `u₀ = b/√(2a)`, `u₁ = L√(a/2) + u₀`. The erf difference is evaluated through erfc on the
/// side where both arguments share a sign, so far-off segments keep their relative accuracy.
#[inline]
fn segment_fraction(u0: f64, u1: f64) -> f64 {
    let t = if u0 >= 0.0 {
        0.5 * (libm::erfc(u0) - libm::erfc(u1))
    } else if u1 <= 0.0 {
        0.5 * (libm::erfc(-u1) - libm::erfc(-u0))
    } else {
        0.5 * (libm::erf(u1) - libm::erf(u0))
    };
    t.max(0.0)
}

/// Exact line integral of a unit-density Gaussian along the segment `origin + t·dir`,
/// `t ∈ [0, length]` (`|dir| = 1`).
pub fn line_integral(rg: &RayGaussian, origin: V3, dir: V3, length: f64) -> f64 {
    match ray_terms(rg, origin, dir) {
        Some(rt) => line_integral_terms(&rt, length),
        None => 0.0,
    }
}

#[inline]
pub fn line_integral_terms(rt: &RayTerms, length: f64) -> f64 {
    let s = (2.0 * rt.a).sqrt();
    let u0 = rt.b / s;
    let u1 = length * rt.a / s + u0;
    let base = (2.0 * std::f64::consts::PI / rt.a).sqrt() * (-0.5 * rt.q).exp();
    let v = base * segment_fraction(u0, u1);
    if v.is_finite() { v } else { 0.0 }
}

/// Value and gradient of [`line_integral`] with respect to the camera-frame centre and the
/// camera-frame precision (full-matrix convention, symmetric). Returns `(value, g_centre, g_prec)`
/// scaled by `weight` (the upstream gradient times density).
pub fn line_integral_backward(
    rg: &RayGaussian,
    origin: V3,
    dir: V3,
    length: f64,
    weight: f64,
) -> (f64, V3, M3) {
    let Some(rt) = ray_terms(rg, origin, dir) else {
        return (0.0, [0.0; 3], [[0.0; 3]; 3]);
    };
    let RayTerms { a, b, q, .. } = rt;
    let s = (2.0 * a).sqrt();
    let u0 = b / s;
    let u1 = length * a / s + u0;
    let base = (2.0 * std::f64::consts::PI / a).sqrt() * (-0.5 * q).exp();
    let frac = segment_fraction(u0, u1);
    let value = base * frac;
    if !(value.is_finite() && base.is_finite()) {
        return (0.0, [0.0; 3], [[0.0; 3]; 3]);
    }
    // ∂ ln base / ∂(a, b, c).
    let dlb_da = -0.5 / a - 0.5 * (b / a) * (b / a);
    let dlb_db = b / a;
    let dlb_dc = -0.5;
    // ∂u/∂(a, b).
    let du0_da = -u0 / (2.0 * a);
    let du0_db = 1.0 / s;
    let du1_da = length / (2.0 * s) + du0_da;
    let du1_db = du0_db;
    let k = 1.0 / std::f64::consts::PI.sqrt();
    let e0 = (-u0 * u0).exp();
    let e1 = (-u1 * u1).exp();
    let dt_da = k * (e1 * du1_da - e0 * du0_da);
    let dt_db = k * (e1 * du1_db - e0 * du0_db);
    let df_da = weight * base * (frac * dlb_da + dt_da);
    let df_db = weight * base * (frac * dlb_db + dt_db);
    let df_dc = weight * base * (frac * dlb_dc);
    let m = [
        origin[0] - rg.centre[0],
        origin[1] - rg.centre[1],
        origin[2] - rg.centre[2],
    ];
    let mut g_prec = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            g_prec[i][j] = df_da * dir[i] * dir[j]
                + df_db * 0.5 * (dir[i] * m[j] + m[i] * dir[j])
                + df_dc * m[i] * m[j];
        }
    }
    // ∂b/∂p = −P d, ∂c/∂p = −2 P m.
    let v = [
        df_db * dir[0] + 2.0 * df_dc * m[0],
        df_db * dir[1] + 2.0 * df_dc * m[1],
        df_db * dir[2] + 2.0 * df_dc * m[2],
    ];
    let pv = mat_vec(&rg.prec, v);
    let g_centre = [-pv[0], -pv[1], -pv[2]];
    let ok =
        g_centre.iter().all(|x| x.is_finite()) && g_prec.iter().flatten().all(|x| x.is_finite());
    if ok {
        (value, g_centre, g_prec)
    } else {
        (value, [0.0; 3], [[0.0; 3]; 3])
    }
}

/// Per-view data of a Gaussian for the exact projector.
#[derive(Clone, Copy, Debug)]
pub struct ExactSplat {
    pub ray_gaussian: RayGaussian,
    /// Detector bounding box `[col_min, col_max, row_min, row_max]` (pixels, may exceed the
    /// detector) of the rays that pass within `cutoff` Mahalanobis units of the centre.
    pub bbox: [f64; 4],
}

/// Lateral shift (camera frame) that moves the projected centre by `offset` pixels.
#[inline]
fn lateral_shift(cam: &Camera, depth: f64, offset: [f64; 2]) -> V3 {
    match cam.projection {
        Projection::Cone => [offset[0] * depth / cam.fx, offset[1] * depth / cam.fy, 0.0],
        Projection::Parallel => [offset[0] / cam.fx, offset[1] / cam.fy, 0.0],
    }
}

/// Prepare a Gaussian for the exact projector. The screen offset moves the centre laterally
/// (parallel to the detector) by the amount that shifts its projection by `offset` pixels.
/// `None` if degenerate or if its cut-off box lies entirely outside `0 ≤ z_c ≤ sdd`.
pub fn exact_splat(
    g: &GaussianGeom,
    cam: &Camera,
    screen_offset: [f64; 2],
    cutoff: f64,
) -> Option<ExactSplat> {
    let shape = shape3(g)?;
    let w = &cam.rotation;
    let mut centre = cam.to_camera(g.mean);
    let shift = lateral_shift(cam, centre[2], screen_offset);
    centre[0] += shift[0];
    centre[1] += shift[1];
    let cov_c = congruence(w, &shape.cov);
    let prec = congruence(w, &shape.prec);
    let h = [
        cutoff * cov_c[0][0].sqrt(),
        cutoff * cov_c[1][1].sqrt(),
        cutoff * cov_c[2][2].sqrt(),
    ];
    if !h.iter().chain(centre.iter()).all(|v| v.is_finite()) {
        return None;
    }
    let (z_lo, z_hi) = (centre[2] - h[2], centre[2] + h[2]);
    if z_hi < 0.0 || z_lo > cam.sdd {
        return None;
    }
    let bbox = match cam.projection {
        Projection::Parallel => [
            cam.fx * (centre[0] - h[0]) + cam.cx,
            cam.fx * (centre[0] + h[0]) + cam.cx,
            cam.fy * (centre[1] - h[1]) + cam.cy,
            cam.fy * (centre[1] + h[1]) + cam.cy,
        ],
        Projection::Cone => {
            // Bounding box of the projected corners of the cut-off box; a box reaching the
            // source plane can be seen anywhere on the detector.
            let z_min = (cam.sdd * 1e-9).max(f64::MIN_POSITIVE);
            if z_lo <= z_min {
                [
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                ]
            } else {
                let mut bb = [
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                ];
                for sx in [-1.0, 1.0] {
                    for sy in [-1.0, 1.0] {
                        for z in [z_lo, z_hi] {
                            let u = cam.fx * (centre[0] + sx * h[0]) / z + cam.cx;
                            let v = cam.fy * (centre[1] + sy * h[1]) / z + cam.cy;
                            bb = [bb[0].min(u), bb[1].max(u), bb[2].min(v), bb[3].max(v)];
                        }
                    }
                }
                bb
            }
        }
    };
    Some(ExactSplat {
        ray_gaussian: RayGaussian { centre, prec },
        bbox,
    })
}

/// Backward of [`exact_splat`]: chain `∂L/∂centre_c`, `∂L/∂Σ_c⁻¹` back to the Gaussian's
/// geometry. Returns the geometry gradient and the screen offset's gradient.
pub fn exact_splat_backward(
    g: &GaussianGeom,
    cam: &Camera,
    screen_offset: [f64; 2],
    g_centre: V3,
    g_prec_c: &M3,
) -> (GeomGrad, [f64; 2]) {
    let Some(shape) = shape3(g) else {
        return (GeomGrad::default(), [0.0; 2]);
    };
    let w = &cam.rotation;
    let depth = cam.to_camera(g.mean)[2];
    let (g_screen, g_depth_extra) = match cam.projection {
        Projection::Cone => (
            [g_centre[0] * depth / cam.fx, g_centre[1] * depth / cam.fy],
            g_centre[0] * screen_offset[0] / cam.fx + g_centre[1] * screen_offset[1] / cam.fy,
        ),
        Projection::Parallel => ([g_centre[0] / cam.fx, g_centre[1] / cam.fy], 0.0),
    };
    let g_t = [g_centre[0], g_centre[1], g_centre[2] + g_depth_extra];
    let g_prec = congruence_t(w, g_prec_c);
    let (g_scale, g_quat) = shape3_backward(&shape, &[[0.0; 3]; 3], &g_prec);
    (
        GeomGrad {
            mean: mat_t_vec(w, g_t),
            scale: g_scale,
            quat: g_quat,
        },
        g_screen,
    )
}
