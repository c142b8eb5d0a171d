//! Per-Gaussian math of the CubeCL kernels, in f32: the port of [`crate::gaussian_math`]'s
//! factors, affine splat, exact ray integral and their backward passes (same formulas, same
//! degenerate-case rules, so the CPU and GPU kernels agree to f32 rounding). A function that can
//! reject a Gaussian returns a value with `ok == false`; its other fields are then unspecified.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::types::{GeomGrad, Mat3, Params, Quat, Vec3, View, finite};

/// `2π`.
const TWO_PI: f32 = 6.283_185_5f32;

/// A Gaussian's covariance factors `Σ = R diag(s²) Rᵀ`.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Factors {
    /// `R(q / |q|)`.
    pub rot: Mat3,
    /// The unit quaternion and the raw one's norm (for the quaternion's backward).
    pub quat: Quat,
    pub qnorm: f32,
    pub scale: Vec3,
    /// `s²` and `s⁻²`.
    pub s2: Vec3,
    pub inv_s2: Vec3,
    /// False if degenerate: zero or non-finite quaternion, non-positive or non-finite scale,
    /// non-finite mean.
    pub ok: bool,
}

/// The factors of Gaussian `p`.
#[cube]
pub fn factors(p: Params) -> Factors {
    let n = p.quat.norm();
    let mut ok = finite(n) && n > 1.0e-12f32 && p.mean.is_finite();
    let s = p.scale;
    let s2 = s.mul(s);
    let inv = Vec3::new(1.0f32 / s2.x, 1.0f32 / s2.y, 1.0f32 / s2.z);
    if !(s.is_finite() && s2.is_finite() && inv.is_finite()) {
        ok = false;
    }
    if !(s.x > 0.0f32 && s.y > 0.0f32 && s.z > 0.0f32) {
        ok = false;
    }
    if !(s2.x > 0.0f32 && s2.y > 0.0f32 && s2.z > 0.0f32) {
        ok = false;
    }
    if !(inv.x > 0.0f32 && inv.y > 0.0f32 && inv.z > 0.0f32) {
        ok = false;
    }
    let q = p.quat.scale(1.0f32 / n);
    Factors {
        rot: q.rotation(),
        quat: q,
        qnorm: n,
        scale: s,
        s2,
        inv_s2: inv,
        ok,
    }
}

/// `∂L/∂q` of the raw quaternion from `g = ∂L/∂R` (`f` the factors).
#[cube]
pub fn quat_backward(f: Factors, g: Mat3) -> Quat {
    let (w, x, y, z) = (f.quat.w, f.quat.x, f.quat.y, f.quat.z);
    let (g0, g1, g2) = (g.r0.x, g.r0.y, g.r0.z);
    let (g3, g4, g5) = (g.r1.x, g.r1.y, g.r1.z);
    let (g6, g7, g8) = (g.r2.x, g.r2.y, g.r2.z);
    let gw = 2.0f32 * (-z * g1 + y * g2 + z * g3 - x * g5 - y * g6 + x * g7);
    let gx = 2.0f32
        * (y * g1 + z * g2 + y * g3 - 2.0f32 * x * g4 - w * g5 + z * g6 + w * g7 - 2.0f32 * x * g8);
    let gy = 2.0f32
        * (-2.0f32 * y * g0 + x * g1 + w * g2 + x * g3 + z * g5 - w * g6 + z * g7
            - 2.0f32 * y * g8);
    let gz = 2.0f32
        * (-2.0f32 * z * g0 - w * g1 + x * g2 + w * g3 - 2.0f32 * z * g4
            + y * g5
            + x * g6
            + y * g7);
    let radial = gw * w + gx * x + gy * y + gz * z;
    let n = f.qnorm;
    Quat::new(
        (gw - w * radial) / n,
        (gx - x * radial) / n,
        (gy - y * radial) / n,
        (gz - z * radial) / n,
    )
}

/// `diag Σ`: the covariance's variance along each world axis, `Σ_aa = Σ_j R_aj² s_j²`.
#[cube]
pub fn variances(f: Factors) -> Vec3 {
    Vec3::new(
        f.rot.r0.mul(f.rot.r0).dot(f.s2),
        f.rot.r1.mul(f.rot.r1).dot(f.s2),
        f.rot.r2.mul(f.rot.r2).dot(f.s2),
    )
}

/// A Gaussian's affine splat in one view, as [`crate::gaussian_math::splat`], with the
/// intermediate terms its backward needs. Nothing 3×3 is multiplied out: with `A = W R` the
/// Gaussian's axes in the camera frame, `Σ₂D = B diag(s²) Bᵀ` with `B = J A` (2×3), and
/// `κ = r̂ᵀ Σ_c⁻¹ r̂ = Σ_j c_j² / s_j²` with `c = Aᵀ r̂`.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Splat {
    pub f: Factors,
    /// `A = W R`.
    pub axes: Mat3,
    /// The centre in camera coordinates.
    pub t: Vec3,
    /// The rows of the projection Jacobian `J` (2×3).
    pub j0: Vec3,
    pub j1: Vec3,
    /// The unit direction to the centre (parallel beam: the viewing axis).
    pub rhat: Vec3,
    /// `c = Aᵀ r̂`.
    pub c: Vec3,
    /// The rows of `B = J A` as `Aᵀ J_r`.
    pub b0: Vec3,
    pub b1: Vec3,
    pub kappa: f32,
    /// The integration factor `μ = √(2π/κ)`.
    pub mu: f32,
    /// `Σ₂D⁻¹` as `(a, b, c)`.
    pub conic: Vec3,
    /// The projected centre with the screen offset (pixels).
    pub mx: f32,
    pub my: f32,
    /// Half-extent of the cut-off box (pixels).
    pub hx: f32,
    pub hy: f32,
    pub ok: bool,
}

/// The affine splat of Gaussian `p` in view `cam` with screen offset `(ox, oy)` (pixels);
/// `ok == false` if it is degenerate or (cone beam) not in front of the near plane.
///
/// `det Σ₂D` is summed from the 2×2 minors of `B` (Cauchy–Binet), free of the cancellation of
/// `s00 s11 − s01²` in f32.
#[cube]
pub fn splat(p: Params, cam: View, ox: f32, oy: f32, cutoff: f32, near_fraction: f32) -> Splat {
    let f = factors(p);
    let mut ok = f.ok;
    let axes = cam.rot.mul(f.rot);
    let t = cam.to_camera(p.mean);
    let mut j0 = Vec3::new(cam.fx, 0.0f32, 0.0f32);
    let mut j1 = Vec3::new(0.0f32, cam.fy, 0.0f32);
    let mut rhat = Vec3::new(0.0f32, 0.0f32, 1.0f32);
    let mut px = cam.fx * t.x + cam.cx;
    let mut py = cam.fy * t.y + cam.cy;
    if cam.cone {
        if !(t.z > near_fraction * cam.sdd) {
            ok = false;
        }
        let iz = 1.0f32 / t.z;
        j0 = Vec3::new(cam.fx * iz, 0.0f32, -cam.fx * t.x * iz * iz);
        j1 = Vec3::new(0.0f32, cam.fy * iz, -cam.fy * t.y * iz * iz);
        rhat = t.scale(1.0f32 / t.length());
        px = cam.fx * t.x * iz + cam.cx;
        py = cam.fy * t.y * iz + cam.cy;
    }
    let c = axes.t_mul_vec(rhat);
    let b0 = axes.t_mul_vec(j0);
    let b1 = axes.t_mul_vec(j1);
    let kappa = c.mul(c).dot(f.inv_s2);
    let mu = f32::sqrt(TWO_PI / kappa);
    if !(kappa > 0.0f32 && finite(mu)) {
        ok = false;
    }
    let s00 = b0.mul(b0).dot(f.s2);
    let s01 = b0.mul(b1).dot(f.s2);
    let s11 = b1.mul(b1).dot(f.s2);
    // det = Σ_{j<l} s_j² s_l² (b0_j b1_l − b0_l b1_j)².
    let m01 = b0.x * b1.y - b0.y * b1.x;
    let m02 = b0.x * b1.z - b0.z * b1.x;
    let m12 = b0.y * b1.z - b0.z * b1.y;
    let det =
        f.s2.x * f.s2.y * m01 * m01 + f.s2.x * f.s2.z * m02 * m02 + f.s2.y * f.s2.z * m12 * m12;
    if !(finite(det) && det > 0.0f32 && s00 > 0.0f32 && s11 > 0.0f32) {
        ok = false;
    }
    let mx = px + ox;
    let my = py + oy;
    let hx = cutoff * f32::sqrt(s00);
    let hy = cutoff * f32::sqrt(s11);
    if !(finite(mx) && finite(my) && finite(hx) && finite(hy)) {
        ok = false;
    }
    Splat {
        f,
        axes,
        t,
        j0,
        j1,
        rhat,
        c,
        b0,
        b1,
        kappa,
        mu,
        conic: Vec3::new(s11 / det, -s01 / det, s00 / det),
        mx,
        my,
        hx,
        hy,
        ok,
    }
}

/// Chain the image-space gradient of a splat (`∂L/∂mean` `(gmx, gmy)`, `∂L/∂conic`
/// `(g_a, g_b, g_c)`, `∂L/∂μ`) to the Gaussian's geometry, as
/// [`crate::gaussian_math::splat_backward_with`]; `cam` is the splat's view.
#[cube]
pub fn splat_backward(
    s: Splat,
    cam: View,
    gmx: f32,
    gmy: f32,
    g_conic: Vec3,
    g_mu: f32,
) -> GeomGrad {
    let (ca, cb, cc) = (s.conic.x, s.conic.y, s.conic.z);
    let (ga, gb, gc) = (g_conic.x, g_conic.y, g_conic.z);
    // G_Σ2D = −C G_C C (symmetrised).
    let cg00 = ca * ga + cb * gb;
    let cg01 = ca * gb + cb * gc;
    let cg10 = cb * ga + cc * gb;
    let cg11 = cb * gb + cc * gc;
    let g00 = -(cg00 * ca + cg01 * cb);
    let g01 = 0.5f32 * (-(cg00 * cb + cg01 * cc) - (cg10 * ca + cg11 * cb));
    let g11 = -(cg10 * cb + cg11 * cc);
    let g_kappa = g_mu * (-0.5f32 * s.mu / s.kappa);
    let f = s.f;
    // G_B (rows gb0, gb1) and G_c.
    let gb0 = s.b0.scale(g00).add(s.b1.scale(g01)).mul(f.s2).scale(2.0f32);
    let gb1 = s.b0.scale(g01).add(s.b1.scale(g11)).mul(f.s2).scale(2.0f32);
    let gcv = s.c.mul(f.inv_s2).scale(2.0f32 * g_kappa);
    let g_s2 =
        s.b0.mul(s.b0)
            .scale(g00)
            .add(s.b0.mul(s.b1).scale(2.0f32 * g01))
            .add(s.b1.mul(s.b1).scale(g11))
            .sub(s.c.mul(s.c).mul(f.inv_s2).mul(f.inv_s2).scale(g_kappa));
    // G_A = Jᵀ G_B + r̂ G_cᵀ; G_R = Wᵀ G_A.
    let g_axes = Mat3::outer(s.j0, gb0)
        .add(Mat3::outer(s.j1, gb1))
        .add(Mat3::outer(s.rhat, gcv));
    let g_rot = cam.rot.transpose().mul(g_axes);
    // The mean: through the projected centre, J(t) and r̂(t).
    let mut gt = s.j0.scale(gmx).add(s.j1.scale(gmy));
    if cam.cone {
        let t = s.t;
        // G_J = G_B Aᵀ: the entries the Jacobian's t-dependence reaches.
        let gj00 = gb0.dot(s.axes.r0);
        let gj02 = gb0.dot(s.axes.r2);
        let gj11 = gb1.dot(s.axes.r1);
        let gj12 = gb1.dot(s.axes.r2);
        let iz = 1.0f32 / t.z;
        let iz2 = iz * iz;
        gt = gt.add(Vec3::new(
            gj02 * (-cam.fx * iz2),
            gj12 * (-cam.fy * iz2),
            gj00 * (-cam.fx * iz2)
                + gj02 * (2.0f32 * cam.fx * t.x * iz2 * iz)
                + gj11 * (-cam.fy * iz2)
                + gj12 * (2.0f32 * cam.fy * t.y * iz2 * iz),
        ));
        // r̂ = t/|t|: G_t += (I − r̂r̂ᵀ) G_r̂ / |t|, G_r̂ = A G_c.
        let gr = s.axes.mul_vec(gcv);
        let along = s.rhat.dot(gr);
        gt = gt.add(gr.sub(s.rhat.scale(along)).scale(1.0f32 / t.length()));
    }
    GeomGrad {
        mean: cam.rot.t_mul_vec(gt),
        scale: f.scale.mul(g_s2).scale(2.0f32),
        quat: quat_backward(f, g_rot),
    }
}

// ---------------------------------------------------------------------------------------------
// Exact line integral (the f32 port of `gaussian_math::line_integral`, reformulated so that no
// step subtracts two large coordinates).

/// `erfc(x)` with a fractional error below 1.2e-7 for every `x` (the Chebyshev fit of Numerical
/// Recipes §6.2), so far tails keep their relative accuracy in f32.
#[cube]
pub fn erfc(x: f32) -> f32 {
    let z = f32::abs(x);
    let t = 1.0f32 / (1.0f32 + 0.5f32 * z);
    let p = -1.135_204f32 + t * (1.488_515_9f32 + t * (-0.822_152_23f32 + t * 0.170_872_77f32));
    let p = -0.186_288_06f32 + t * (0.278_868_07f32 + t * p);
    let p = 0.374_091_96f32 + t * (0.096_784_18f32 + t * p);
    let p = -1.265_512_2f32 + t * (1.000_023_7f32 + t * p);
    let r = t * f32::exp(-z * z + p);
    select(x >= 0.0f32, r, 2.0f32 - r)
}

/// `½[erf(u₁) − erf(u₀)]` through erfc on the side where both arguments share a sign, as the
/// CPU's `segment_fraction`; clamped at 0.
#[cube]
pub fn segment_fraction(u0: f32, u1: f32) -> f32 {
    let mut t = 0.5f32 * (2.0f32 - erfc(-u0) - erfc(u1));
    if u0 >= 0.0f32 {
        t = 0.5f32 * (erfc(u0) - erfc(u1));
    } else if u1 <= 0.0f32 {
        t = 0.5f32 * (erfc(-u1) - erfc(-u0));
    }
    f32::max(t, 0.0f32)
}

/// A Gaussian prepared for exact integrals in one view (camera frame): the centre with the
/// screen offset applied, the axes `A_j = (W R)_j` as rows, the scales.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct RayGaussian {
    pub centre: Vec3,
    pub axes: Mat3,
    pub scale: Vec3,
}

#[cube]
impl RayGaussian {
    /// `1 / (s_k s_l)` for each axis `j` ({j, k, l} = {0, 1, 2}).
    pub fn cofactor_scales(self) -> Vec3 {
        let s = self.scale;
        Vec3::new(
            1.0f32 / (s.y * s.z),
            1.0f32 / (s.z * s.x),
            1.0f32 / (s.x * s.y),
        )
    }
}

/// One pixel's ray against a [`RayGaussian`]: the terms of [`exact_ray`] and the integral.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Ray {
    /// Direction `D` (z component 1), offset `w` at the centre's depth (z = 0), `c = w × D`.
    pub d: Vec3,
    pub w: Vec3,
    pub c: Vec3,
    /// `A_j · D`, `A_j · w`, `A_j · c`.
    pub ad: Vec3,
    pub aw: Vec3,
    pub ac: Vec3,
    /// `a = Dᵀ Σ_c⁻¹ D`, `b = Dᵀ Σ_c⁻¹ w`, `Q = a·q = Σ_j (A_j · c)² / (s_k s_l)²`, `√(2a)`.
    pub a: f32,
    pub b: f32,
    pub qq: f32,
    pub s: f32,
    /// erf arguments at the segment's ends.
    pub u0: f32,
    pub u1: f32,
    /// `|D| √(2π/a) e^{−q/2}`, the segment fraction, and the integral `base · t`.
    pub base: f32,
    pub t: f32,
    pub value: f32,
    /// False if the ray passes beyond the cut-off (`q > cut²`) or the terms are degenerate.
    pub ok: bool,
}

/// The exact integral of unit-density `g` along the ray of pixel `(col, row)` of view `cam`.
///
/// The ray is parametrised by its depth `τ` (cone: points `τ D` with `D = ((col − cx)/fx,
/// (row − cy)/fy, 1)`; parallel: `(L, τ)` with `D = (0, 0, 1)`), shifted to the centre's depth,
/// `σ = τ − z_c`: the offset from the centre is `σ D + w`, `w = (z_c L − p_xy, 0)` (cone) or
/// `(L − p_xy, 0)` (parallel), `L` the pixel's lateral coordinate. The segment runs from the
/// source (cone) or start plane (`σ₀ = −z_c`) to the detector (`σ₁ = sdd − z_c`), and
/// `∫ e^{−½ q(σ)} |D| dσ = |D| √(2π/a) e^{−q/2} ½[erf(u₁) − erf(u₀)]`, `u_i = (a σ_i + b)/√(2a)`.
///
/// The line's Mahalanobis distance is taken in cofactor form,
/// `q = Σ_j (A_j · (w × D))² / (s_k s_l)² / a`, the 3D analogue of the affine splat's
/// Cauchy–Binet determinant. It never forms a thin axis' coordinate of a far offset, so a sheet
/// crossed far from its centre keeps its accuracy in f32 (the form `|w|² − b²/a` loses
/// `ε · |w| / s_min`).
#[cube]
pub fn exact_ray(g: RayGaussian, cam: View, col: f32, row: f32, cut2: f32) -> Ray {
    let lx = (col - cam.cx) / cam.fx;
    let ly = (row - cam.cy) / cam.fy;
    let z = g.centre.z;
    let mut d = Vec3::new(0.0f32, 0.0f32, 1.0f32);
    let mut w = Vec3::new(lx - g.centre.x, ly - g.centre.y, 0.0f32);
    let mut dlen = 1.0f32;
    if cam.cone {
        d = Vec3::new(lx, ly, 1.0f32);
        w = Vec3::new(z * lx - g.centre.x, z * ly - g.centre.y, 0.0f32);
        dlen = d.length();
    }
    // c = w × D with w_z = 0, D_z = 1.
    let c = Vec3::new(w.y, -w.x, w.x * d.y - w.y * d.x);
    let ad = g.axes.mul_vec(d);
    let aw = g.axes.mul_vec(w);
    let ac = g.axes.mul_vec(c);
    let inv_s = Vec3::new(1.0f32 / g.scale.x, 1.0f32 / g.scale.y, 1.0f32 / g.scale.z);
    let ed = ad.mul(inv_s);
    let a = ed.dot(ed);
    let b = ed.dot(aw.mul(inv_s));
    let n = ac.mul(g.cofactor_scales());
    let qq = n.dot(n);
    let q = qq / a;
    let mut ok = a > 0.0f32 && finite(a) && finite(b) && finite(qq) && q <= cut2;
    let s = f32::sqrt(2.0f32 * a);
    let u0 = (b - a * z) / s;
    let u1 = (a * (cam.sdd - z) + b) / s;
    let base = dlen * f32::sqrt(TWO_PI / a) * f32::exp(-0.5f32 * q);
    let t = segment_fraction(u0, u1);
    let value = base * t;
    if !(finite(value) && finite(base)) {
        ok = false;
    }
    Ray {
        d,
        w,
        c,
        ad,
        aw,
        ac,
        a,
        b,
        qq,
        s,
        u0,
        u1,
        base,
        t,
        value,
        ok,
    }
}
