//! Per-Gaussian and per-ray math shared by the forward and backward kernels.
//!
//! Everything here is a plain `f64` function on plain numbers, so the CPU kernels (and later the
//! CubeCL port) call the same code for the forward value and for its hand-written derivative.
//!
//! Conventions:
//! * a Gaussian is `ρ · exp(−½ (x − p)ᵀ Σ⁻¹ (x − p))` with `Σ = R diag(s²) Rᵀ`, `R = R(q / |q|)`,
//!   quaternions `(w, x, y, z)`; the quaternion is normalised here and its gradient is taken
//!   with respect to the raw (unnormalised) value;
//! * symmetric-matrix gradients use the full-matrix convention: `G[i][j] = ∂L/∂A[i][j]` with the
//!   two off-diagonal entries treated as independent, so every `G` is symmetric;
//! * detector coordinates are pixels with pixel centres at integers (see [`crate::camera`]).
//!
//! A Gaussian with a zero or non-finite quaternion, a non-positive or non-finite scale, or a
//! non-finite mean is *degenerate*: every function returns `None` for it and the kernels skip it,
//! so it contributes zero to outputs and receives zero gradients.

mod affine;
mod exact;
mod voxel;

pub use affine::*;
pub use exact::*;
pub use voxel::*;

use crate::camera::{Camera, Projection};

pub type V3 = [f64; 3];
pub type M3 = [[f64; 3]; 3];

/// √(2π).
pub const SQRT_2PI: f64 = 2.506_628_274_631_000_7;

// ---------------------------------------------------------------------------------------------
// Small linear algebra.

#[inline]
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub fn mat_vec(m: &M3, v: V3) -> V3 {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

/// `mᵀ v`.
#[inline]
pub fn mat_t_vec(m: &M3, v: V3) -> V3 {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}

#[inline]
pub fn mat_mul(a: &M3, b: &M3) -> M3 {
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    out
}

#[inline]
pub fn transpose(a: &M3) -> M3 {
    [
        [a[0][0], a[1][0], a[2][0]],
        [a[0][1], a[1][1], a[2][1]],
        [a[0][2], a[1][2], a[2][2]],
    ]
}

/// `A · diag(d) · Aᵀ`.
#[inline]
pub fn sandwich_diag(a: &M3, d: V3) -> M3 {
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in i..3 {
            let v = a[i][0] * d[0] * a[j][0] + a[i][1] * d[1] * a[j][1] + a[i][2] * d[2] * a[j][2];
            out[i][j] = v;
            out[j][i] = v;
        }
    }
    out
}

/// `A · S · Aᵀ`.
#[inline]
pub fn congruence(a: &M3, s: &M3) -> M3 {
    mat_mul(&mat_mul(a, s), &transpose(a))
}

/// `Aᵀ · S · A`.
#[inline]
pub fn congruence_t(a: &M3, s: &M3) -> M3 {
    mat_mul(&mat_mul(&transpose(a), s), a)
}

/// Packs a symmetric matrix as `[xx, xy, xz, yy, yz, zz]`.
#[inline]
pub fn sym_pack(m: &M3) -> [f64; 6] {
    [m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]]
}

/// Inverse of [`sym_pack`].
#[inline]
pub fn sym_unpack(p: &[f64; 6]) -> M3 {
    [[p[0], p[1], p[2]], [p[1], p[3], p[4]], [p[2], p[4], p[5]]]
}

// ---------------------------------------------------------------------------------------------
// Gaussian shape.

/// One Gaussian's geometry in world coordinates (length units of the scene).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussianGeom {
    pub mean: V3,
    /// Standard deviations along the Gaussian's own axes (positive).
    pub scale: V3,
    /// Rotation quaternion `(w, x, y, z)`; need not be normalised.
    pub quat: [f64; 4],
}

/// Gradient of a scalar loss with respect to [`GaussianGeom`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GeomGrad {
    pub mean: V3,
    pub scale: V3,
    pub quat: [f64; 4],
}

/// Rotation matrix of a unit quaternion `(w, x, y, z)`.
pub fn quat_to_rotation(q: [f64; 4]) -> M3 {
    let [w, x, y, z] = q;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// `∂L/∂q` for a unit quaternion given `G_R = ∂L/∂R`.
fn rotation_grad_to_quat(q: [f64; 4], g: &M3) -> [f64; 4] {
    let [w, x, y, z] = q;
    let gw =
        2.0 * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] + x * g[2][1]);
    let gx = 2.0
        * (y * g[0][1] + z * g[0][2] + y * g[1][0] - 2.0 * x * g[1][1] - w * g[1][2]
            + z * g[2][0]
            + w * g[2][1]
            - 2.0 * x * g[2][2]);
    let gy = 2.0
        * (-2.0 * y * g[0][0] + x * g[0][1] + w * g[0][2] + x * g[1][0] + z * g[1][2]
            - w * g[2][0]
            + z * g[2][1]
            - 2.0 * y * g[2][2]);
    let gz = 2.0
        * (-2.0 * z * g[0][0] - w * g[0][1] + x * g[0][2] + w * g[1][0] - 2.0 * z * g[1][1]
            + y * g[1][2]
            + x * g[2][0]
            + y * g[2][1]);
    [gw, gx, gy, gz]
}

/// The covariance and precision of a Gaussian, with what the backward pass needs to undo them.
#[derive(Clone, Copy, Debug)]
pub struct Shape3 {
    /// `Σ = R diag(s²) Rᵀ`.
    pub cov: M3,
    /// `Σ⁻¹ = R diag(s⁻²) Rᵀ` (built from the factors, never by inversion).
    pub prec: M3,
    pub rot: M3,
    /// The normalised quaternion and the raw quaternion's norm.
    pub unit_quat: [f64; 4],
    pub quat_norm: f64,
    pub scale: V3,
}

/// The factors of `Σ = R diag(s²) Rᵀ`, validated, without multiplying them out.
#[derive(Clone, Copy, Debug)]
struct Factors {
    rot: M3,
    unit_quat: [f64; 4],
    quat_norm: f64,
    scale: V3,
    /// `s²` and `s⁻²` per axis.
    s2: V3,
    inv_s2: V3,
}

/// [`Factors`] of a Gaussian, or `None` if it is degenerate.
fn factors(g: &GaussianGeom) -> Option<Factors> {
    let n2: f64 = g.quat.iter().map(|v| v * v).sum();
    let n = n2.sqrt();
    if !(n.is_finite() && n > 1e-12) {
        return None;
    }
    if !g.mean.iter().all(|v| v.is_finite()) {
        return None;
    }
    if !g.scale.iter().all(|s| s.is_finite() && *s > 0.0) {
        return None;
    }
    let unit_quat = [g.quat[0] / n, g.quat[1] / n, g.quat[2] / n, g.quat[3] / n];
    let s2 = g.scale.map(|s| s * s);
    let inv_s2 = s2.map(|v| 1.0 / v);
    if !s2
        .iter()
        .chain(inv_s2.iter())
        .all(|v| v.is_finite() && *v > 0.0)
    {
        return None;
    }
    Some(Factors {
        rot: quat_to_rotation(unit_quat),
        unit_quat,
        quat_norm: n,
        scale: g.scale,
        s2,
        inv_s2,
    })
}

/// Covariance and precision of a Gaussian, or `None` if it is degenerate.
pub fn shape3(g: &GaussianGeom) -> Option<Shape3> {
    let f = factors(g)?;
    Some(Shape3 {
        cov: sandwich_diag(&f.rot, f.s2),
        prec: sandwich_diag(&f.rot, f.inv_s2),
        rot: f.rot,
        unit_quat: f.unit_quat,
        quat_norm: f.quat_norm,
        scale: f.scale,
    })
}

/// `∂L/∂q` for the raw quaternion `q = |q| · u` given `G_R = ∂L/∂R(u)`.
fn quat_backward(unit_quat: [f64; 4], quat_norm: f64, g_rot: &M3) -> [f64; 4] {
    let g_unit = rotation_grad_to_quat(unit_quat, g_rot);
    let u = unit_quat;
    let radial = g_unit[0] * u[0] + g_unit[1] * u[1] + g_unit[2] * u[2] + g_unit[3] * u[3];
    std::array::from_fn(|k| (g_unit[k] - u[k] * radial) / quat_norm)
}

/// Chain `∂L/∂Σ` and `∂L/∂Σ⁻¹` (world frame, symmetric) back to scale and raw quaternion.
pub fn shape3_backward(sh: &Shape3, g_cov: &M3, g_prec: &M3) -> (V3, [f64; 4]) {
    let r = &sh.rot;
    let s = sh.scale;
    // Rᵀ G R diagonals give the scale gradients; G R D gives the rotation gradient.
    let gr_cov = mat_mul(g_cov, r);
    let gr_prec = mat_mul(g_prec, r);
    let mut g_scale = [0.0; 3];
    let mut g_rot = [[0.0; 3]; 3];
    for i in 0..3 {
        let s2 = s[i] * s[i];
        let inv_s2 = 1.0 / s2;
        let d_cov = r[0][i] * gr_cov[0][i] + r[1][i] * gr_cov[1][i] + r[2][i] * gr_cov[2][i];
        let d_prec = r[0][i] * gr_prec[0][i] + r[1][i] * gr_prec[1][i] + r[2][i] * gr_prec[2][i];
        g_scale[i] = 2.0 * s[i] * d_cov - 2.0 * inv_s2 / s[i] * d_prec;
        for row in 0..3 {
            g_rot[row][i] = 2.0 * (gr_cov[row][i] * s2 + gr_prec[row][i] * inv_s2);
        }
    }
    let g_quat = quat_backward(sh.unit_quat, sh.quat_norm, &g_rot);
    (g_scale, g_quat)
}

// ---------------------------------------------------------------------------------------------
// Quadratic forms evaluated in a cancellation-free factored form.

/// `dᵀ C d` for a symmetric positive-definite 2×2 `C = [[a, b], [b, c]]`, stored as
/// `(a, β = b/a, γ = c − b²/a)` so that `dᵀCd = a (dx + β dy)² + γ dy²` — a sum of two
/// non-negative terms, accurate even for needle-thin footprints (eigenvalue ratio 1e8).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Quad2 {
    pub a: f64,
    pub beta: f64,
    pub gamma: f64,
}

impl Quad2 {
    /// Factor `C`, or `None` if it is not positive definite.
    pub fn new(c: [[f64; 2]; 2]) -> Option<Self> {
        let a = c[0][0];
        if !(a.is_finite() && a > 0.0) {
            return None;
        }
        let beta = c[0][1] / a;
        let gamma = c[1][1] - c[0][1] * beta;
        (gamma.is_finite() && gamma > 0.0 && beta.is_finite()).then_some(Self { a, beta, gamma })
    }

    #[inline]
    pub fn eval(&self, dx: f64, dy: f64) -> f64 {
        let e = dx + self.beta * dy;
        self.a * e * e + self.gamma * dy * dy
    }
}

/// `dᵀ P d` for a symmetric positive-definite 3×3 `P` in the factored form
/// `d0 (dx + l01 dy + l02 dz)² + d1 (dy + l12 dz)² + d2 dz²` (an LDLᵀ factorisation).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Quad3 {
    pub d0: f64,
    pub l01: f64,
    pub l02: f64,
    pub d1: f64,
    pub l12: f64,
    pub d2: f64,
}

impl Quad3 {
    pub fn new(p: &M3) -> Option<Self> {
        let d0 = p[0][0];
        if !(d0.is_finite() && d0 > 0.0) {
            return None;
        }
        let l01 = p[0][1] / d0;
        let l02 = p[0][2] / d0;
        let s00 = p[1][1] - p[0][1] * l01;
        let s01 = p[1][2] - p[0][1] * l02;
        let s11 = p[2][2] - p[0][2] * l02;
        if !(s00.is_finite() && s00 > 0.0) {
            return None;
        }
        let l12 = s01 / s00;
        let d2 = s11 - s01 * l12;
        (d2.is_finite() && d2 > 0.0 && l01.is_finite() && l02.is_finite() && l12.is_finite())
            .then_some(Self {
                d0,
                l01,
                l02,
                d1: s00,
                l12,
                d2,
            })
    }

    #[inline]
    pub fn eval(&self, d: V3) -> f64 {
        let e0 = d[0] + self.l01 * d[1] + self.l02 * d[2];
        let e1 = d[1] + self.l12 * d[2];
        self.d0 * e0 * e0 + self.d1 * e1 * e1 + self.d2 * d[2] * d[2]
    }
}

#[cfg(test)]
mod tests;
