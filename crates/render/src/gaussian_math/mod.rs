//! Per-Gaussian and per-ray math shared by the forward and backward kernels.
//!
//! Everything here is a plain `f64` function on plain numbers, so the CPU kernels (and later the
//! CubeCL port) call the same code for the forward value and for its hand-written derivative.
//! The factors and the affine splat with its chain rule are generic over [`Real`]: the same
//! code runs on one Gaussian (`f64`) or on four in lanes ([`F64x4`]), bit for bit alike.
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
//! non-finite mean is *degenerate*: every function returns `None` for it (the lane forms flag it
//! in their mask) and the kernels skip it, so it contributes zero to outputs and receives zero
//! gradients.

mod affine;
mod exact;
mod real;
mod voxel;

pub use affine::*;
pub use exact::*;
pub use real::*;
pub use voxel::*;

use crate::camera::{Camera, Projection};

pub type V3 = [f64; 3];
pub type M3 = [[f64; 3]; 3];

/// √(2π).
pub const SQRT_2PI: f64 = 2.506_628_274_631_000_7;

// ---------------------------------------------------------------------------------------------
// Small linear algebra.

#[inline(always)]
pub fn dot<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub fn mat_vec<T: Real>(m: &[[T; 3]; 3], v: [T; 3]) -> [T; 3] {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

/// `mᵀ v`.
#[inline(always)]
pub fn mat_t_vec<T: Real>(m: &[[T; 3]; 3], v: [T; 3]) -> [T; 3] {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}

/// `[f(0), f(1)]`, and [`arr3`], [`arr4`]: `std::array::from_fn` spelt out. In a large kernel
/// the inliner can leave `from_fn`'s machinery out of line, where it runs without the kernel's
/// AVX and passes its arrays through memory; a literal array has nothing to leave out. The
/// elements are computed in the same order.
#[inline(always)]
pub(crate) fn arr2<T>(mut f: impl FnMut(usize) -> T) -> [T; 2] {
    [f(0), f(1)]
}

/// See [`arr2`].
#[inline(always)]
pub(crate) fn arr3<T>(mut f: impl FnMut(usize) -> T) -> [T; 3] {
    [f(0), f(1), f(2)]
}

/// See [`arr2`].
#[inline(always)]
pub(crate) fn arr4<T>(mut f: impl FnMut(usize) -> T) -> [T; 4] {
    [f(0), f(1), f(2), f(3)]
}

#[inline(always)]
pub fn mat_mul<T: Real>(a: &[[T; 3]; 3], b: &[[T; 3]; 3]) -> [[T; 3]; 3] {
    arr3(|i| arr3(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j]))
}

#[inline(always)]
pub fn transpose<T: Copy>(a: &[[T; 3]; 3]) -> [[T; 3]; 3] {
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

/// One Gaussian's geometry in world coordinates (length units of the scene); with
/// `T = `[`F64x4`], four Gaussians' (lane `j` of every value is Gaussian `j`'s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussianGeom<T = f64> {
    pub mean: [T; 3],
    /// Standard deviations along the Gaussian's own axes (positive).
    pub scale: [T; 3],
    /// Rotation quaternion `(w, x, y, z)`; need not be normalised.
    pub quat: [T; 4],
}

impl GaussianGeom<F64x4> {
    /// Four Gaussians in lanes: lane `j` is `geom(j)`.
    #[inline(always)]
    pub fn lanes(geom: impl Fn(usize) -> GaussianGeom) -> Self {
        let g: [GaussianGeom; F64_LANES] = arr4(geom);
        Self {
            mean: F64x4::gather(|j| g[j].mean),
            scale: F64x4::gather(|j| g[j].scale),
            quat: F64x4::gather(|j| g[j].quat),
        }
    }
}

/// Gradient of a scalar loss with respect to [`GaussianGeom`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GeomGrad<T = f64> {
    pub mean: [T; 3],
    pub scale: [T; 3],
    pub quat: [T; 4],
}

impl GeomGrad<F64x4> {
    /// The gradient in lane `j`.
    #[inline(always)]
    pub fn lane(&self, j: usize) -> GeomGrad {
        GeomGrad {
            mean: self.mean.map(|v| v.0[j]),
            scale: self.scale.map(|v| v.0[j]),
            quat: self.quat.map(|v| v.0[j]),
        }
    }
}

/// Rotation matrix of a unit quaternion `(w, x, y, z)`.
#[inline(always)]
pub fn quat_to_rotation<T: Real>(q: [T; 4]) -> [[T; 3]; 3] {
    let [w, x, y, z] = q;
    let (one, two) = (T::splat(1.0), T::splat(2.0));
    [
        [
            one - two * (y * y + z * z),
            two * (x * y - w * z),
            two * (x * z + w * y),
        ],
        [
            two * (x * y + w * z),
            one - two * (x * x + z * z),
            two * (y * z - w * x),
        ],
        [
            two * (x * z - w * y),
            two * (y * z + w * x),
            one - two * (x * x + y * y),
        ],
    ]
}

/// `∂L/∂q` for a unit quaternion given `G_R = ∂L/∂R`.
#[inline(always)]
fn rotation_grad_to_quat<T: Real>(q: [T; 4], g: &[[T; 3]; 3]) -> [T; 4] {
    let [w, x, y, z] = q;
    let two = T::splat(2.0);
    let gw =
        two * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] + x * g[2][1]);
    let gx = two
        * (y * g[0][1] + z * g[0][2] + y * g[1][0] - two * x * g[1][1] - w * g[1][2]
            + z * g[2][0]
            + w * g[2][1]
            - two * x * g[2][2]);
    let gy = two
        * (-two * y * g[0][0] + x * g[0][1] + w * g[0][2] + x * g[1][0] + z * g[1][2]
            - w * g[2][0]
            + z * g[2][1]
            - two * y * g[2][2]);
    let gz = two
        * (-two * z * g[0][0] - w * g[0][1] + x * g[0][2] + w * g[1][0] - two * z * g[1][1]
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

/// The factors of `Σ = R diag(s²) Rᵀ`, without multiplying them out.
#[derive(Clone, Copy, Debug)]
struct Factors<T = f64> {
    rot: [[T; 3]; 3],
    unit_quat: [T; 4],
    quat_norm: T,
    scale: [T; 3],
    /// `s²` and `s⁻²` per axis.
    s2: [T; 3],
    inv_s2: [T; 3],
}

/// [`Factors`] of a Gaussian, and whether it is not degenerate.
#[inline(always)]
fn factors_masked<T: Real>(g: &GaussianGeom<T>) -> (Factors<T>, T::Mask) {
    let q = g.quat;
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let (zero, one) = (T::splat(0.0), T::splat(1.0));
    let mut ok = n.is_finite() & n.gt(T::splat(1e-12));
    for v in g.mean {
        ok = ok & v.is_finite();
    }
    let s2 = g.scale.map(|s| s * s);
    let inv_s2 = s2.map(|v| one / v);
    for v in g.scale.into_iter().chain(s2).chain(inv_s2) {
        ok = ok & v.is_finite() & v.gt(zero);
    }
    let unit_quat = q.map(|v| v / n);
    let f = Factors {
        rot: quat_to_rotation(unit_quat),
        unit_quat,
        quat_norm: n,
        scale: g.scale,
        s2,
        inv_s2,
    };
    (f, ok)
}

/// Covariance and precision of a Gaussian, or `None` if it is degenerate.
pub fn shape3(g: &GaussianGeom) -> Option<Shape3> {
    let (f, ok) = factors_masked(g);
    ok.then_some(Shape3 {
        cov: sandwich_diag(&f.rot, f.s2),
        prec: sandwich_diag(&f.rot, f.inv_s2),
        rot: f.rot,
        unit_quat: f.unit_quat,
        quat_norm: f.quat_norm,
        scale: f.scale,
    })
}

/// `∂L/∂q` for the raw quaternion `q = |q| · u` given `G_R = ∂L/∂R(u)`.
#[inline(always)]
fn quat_backward<T: Real>(unit_quat: [T; 4], quat_norm: T, g_rot: &[[T; 3]; 3]) -> [T; 4] {
    let g_unit = rotation_grad_to_quat(unit_quat, g_rot);
    let u = unit_quat;
    let radial = g_unit[0] * u[0] + g_unit[1] * u[1] + g_unit[2] * u[2] + g_unit[3] * u[3];
    arr4(|k| (g_unit[k] - u[k] * radial) / quat_norm)
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
pub struct Quad2<T = f64> {
    pub a: T,
    pub beta: T,
    pub gamma: T,
}

impl<T: Real> Quad2<T> {
    /// Factor `C`, and whether it is positive definite.
    #[inline(always)]
    pub fn new_masked(c: [[T; 2]; 2]) -> (Self, T::Mask) {
        let a = c[0][0];
        let beta = c[0][1] / a;
        let gamma = c[1][1] - c[0][1] * beta;
        let zero = T::splat(0.0);
        let ok = a.is_finite() & a.gt(zero) & gamma.is_finite() & gamma.gt(zero) & beta.is_finite();
        (Self { a, beta, gamma }, ok)
    }
}

impl Quad2 {
    /// Factor `C`, or `None` if it is not positive definite.
    pub fn new(c: [[f64; 2]; 2]) -> Option<Self> {
        let (q, ok) = Self::new_masked(c);
        ok.then_some(q)
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
