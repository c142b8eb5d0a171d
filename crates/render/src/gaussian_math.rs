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

// ---------------------------------------------------------------------------------------------
// Affine (splatting) projection.

/// Per-view data of one Gaussian in the local-affine (EWA) approximation.
///
/// The image of the Gaussian is `ρ · μ · exp(−½ (x − mean)ᵀ Σ₂D⁻¹ (x − mean))` with `x` the pixel
/// centre in pixels, `μ = √(2π / (r̂ᵀ Σ_c⁻¹ r̂))` the exact line integral of the unit-density
/// Gaussian along the ray through its centre (`r̂` the unit direction from the source to the
/// centre, or the viewing axis for parallel beam).
#[derive(Clone, Copy, Debug)]
pub struct Splat {
    /// Projected centre (column, row) in pixels, screen offset included.
    pub mean: [f64; 2],
    /// `Σ₂D⁻¹` in factored form.
    pub conic: Quad2,
    /// `Σ₂D⁻¹` as a matrix `[a, b, c]` (for the backward pass).
    pub conic_mat: [f64; 3],
    /// Integration factor μ (length units).
    pub mu: f64,
    /// Half-extent of the cut-off ellipse's bounding box (pixels): `cutoff · √Σ₂D,ii`.
    pub half_extent: [f64; 2],
}

/// Internals of [`splat`] kept for its backward pass.
///
/// Nothing 3×3 is multiplied out: with `A = W R` the Gaussian's axes in the camera frame,
/// `Σ₂D = B diag(s²) Bᵀ` with `B = J A` (2×3), and `κ = r̂ᵀ Σ_c⁻¹ r̂ = Σ_j c_j² / s_j²` with
/// `c = Aᵀ r̂`.
struct SplatState {
    f: Factors,
    /// `A = W R`.
    axes: M3,
    /// Rows of `B = J A`.
    b: [V3; 2],
    /// `c = Aᵀ r̂`.
    c: V3,
    /// Centre in camera coordinates.
    t: V3,
    /// 2×3 Jacobian of the projection at `t`.
    jac: [[f64; 3]; 2],
    r_hat: V3,
    kappa: f64,
    splat: Splat,
}

fn splat_state(
    g: &GaussianGeom,
    cam: &Camera,
    screen_offset: [f64; 2],
    cutoff: f64,
    near: f64,
) -> Option<SplatState> {
    let f = factors(g)?;
    let axes = mat_mul(&cam.rotation, &f.rot);
    let t = cam.to_camera(g.mean);
    let (jac, r_hat, proj) = match cam.projection {
        Projection::Cone => {
            if t[2].partial_cmp(&near) != Some(std::cmp::Ordering::Greater) {
                return None;
            }
            let iz = 1.0 / t[2];
            let jac = [
                [cam.fx * iz, 0.0, -cam.fx * t[0] * iz * iz],
                [0.0, cam.fy * iz, -cam.fy * t[1] * iz * iz],
            ];
            let len = dot(t, t).sqrt();
            let r_hat = [t[0] / len, t[1] / len, t[2] / len];
            (
                jac,
                r_hat,
                [cam.fx * t[0] * iz + cam.cx, cam.fy * t[1] * iz + cam.cy],
            )
        }
        Projection::Parallel => (
            [[cam.fx, 0.0, 0.0], [0.0, cam.fy, 0.0]],
            [0.0, 0.0, 1.0],
            [cam.fx * t[0] + cam.cx, cam.fy * t[1] + cam.cy],
        ),
    };
    let c = mat_t_vec(&axes, r_hat);
    let kappa = (0..3).map(|j| c[j] * c[j] * f.inv_s2[j]).sum::<f64>();
    let mu = (2.0 * std::f64::consts::PI / kappa).sqrt();
    if !(kappa > 0.0 && mu.is_finite()) {
        return None;
    }
    // Σ₂D = B diag(s²) Bᵀ, B = J A.
    let b = [mat_t_vec(&axes, jac[0]), mat_t_vec(&axes, jac[1])];
    let form = |p: V3, q: V3| (0..3).map(|j| p[j] * q[j] * f.s2[j]).sum::<f64>();
    let s00 = form(b[0], b[0]);
    let s01 = form(b[0], b[1]);
    let s11 = form(b[1], b[1]);
    let det = s00 * s11 - s01 * s01;
    if !(det.is_finite() && det > 0.0 && s00 > 0.0 && s11 > 0.0) {
        return None;
    }
    let conic_mat = [s11 / det, -s01 / det, s00 / det];
    let conic = Quad2::new([[conic_mat[0], conic_mat[1]], [conic_mat[1], conic_mat[2]]])?;
    let mean = [proj[0] + screen_offset[0], proj[1] + screen_offset[1]];
    let half_extent = [cutoff * s00.sqrt(), cutoff * s11.sqrt()];
    if !(mean.iter().chain(half_extent.iter()).all(|v| v.is_finite())) {
        return None;
    }
    Some(SplatState {
        f,
        axes,
        b,
        c,
        t,
        jac,
        r_hat,
        kappa,
        splat: Splat {
            mean,
            conic,
            conic_mat,
            mu,
            half_extent,
        },
    })
}

/// The affine splat of a Gaussian in one view, or `None` if it is degenerate or (cone beam)
/// its centre is not in front of the near plane `z_c > near`.
pub fn splat(
    g: &GaussianGeom,
    cam: &Camera,
    screen_offset: [f64; 2],
    cutoff: f64,
    near: f64,
) -> Option<Splat> {
    splat_state(g, cam, screen_offset, cutoff, near).map(|s| s.splat)
}

/// Loss gradients with respect to one splat's image-space quantities.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplatGrad {
    /// `∂L/∂mean` (pixels⁻¹ · loss).
    pub mean: [f64; 2],
    /// `∂L/∂Σ₂D⁻¹` in the full-matrix convention `[[g_a, g_b], [g_b, g_c]]`, given as `[g_a, g_b, g_c]`.
    pub conic: [f64; 3],
    pub mu: f64,
}

/// Backward of [`splat`]: gradients with respect to the Gaussian's geometry, and the screen
/// offset's gradient (equal to `grad.mean`). Returns zeros for a Gaussian [`splat`] rejects.
pub fn splat_backward(
    g: &GaussianGeom,
    cam: &Camera,
    screen_offset: [f64; 2],
    cutoff: f64,
    near: f64,
    grad: &SplatGrad,
) -> GeomGrad {
    splat_backward_with(g, cam, screen_offset, cutoff, near, |_| *grad)
        .map_or_else(GeomGrad::default, |(geo, _)| geo)
}

/// [`splat_backward`] with the image-space gradient built from the splat itself,
/// `grad(&splat)` (e.g. from pixel moments that need its μ and `Σ₂D⁻¹`), so the splat is
/// computed once. Returns the geometry gradient and the [`SplatGrad`] it chained, or `None`
/// for a Gaussian [`splat`] rejects.
pub fn splat_backward_with(
    g: &GaussianGeom,
    cam: &Camera,
    screen_offset: [f64; 2],
    cutoff: f64,
    near: f64,
    grad: impl FnOnce(&Splat) -> SplatGrad,
) -> Option<(GeomGrad, SplatGrad)> {
    let st = splat_state(g, cam, screen_offset, cutoff, near)?;
    let grad = &grad(&st.splat);
    let w = &cam.rotation;
    let jac = &st.jac;
    let [ca, cb, cc] = st.splat.conic_mat;
    let [ga, gb, gc] = grad.conic;
    // G_Σ2D = −C G_C C.
    let cg = [
        [ca * ga + cb * gb, ca * gb + cb * gc],
        [cb * ga + cc * gb, cb * gb + cc * gc],
    ];
    let g2 = [
        [
            -(cg[0][0] * ca + cg[0][1] * cb),
            -(cg[0][0] * cb + cg[0][1] * cc),
        ],
        [
            -(cg[1][0] * ca + cg[1][1] * cb),
            -(cg[1][0] * cb + cg[1][1] * cc),
        ],
    ];
    let g2s = 0.5 * (g2[0][1] + g2[1][0]);
    let g2 = [[g2[0][0], g2s], [g2s, g2[1][1]]];
    let f = &st.f;
    let (a, b, c) = (&st.axes, &st.b, st.c);
    // Σ₂D = B D Bᵀ (D = diag(s²)): G_B = 2 G_Σ2D B D, G_D,j = Σ_ab G_ab B_aj B_bj.
    let g_b: [V3; 2] = std::array::from_fn(|r| {
        std::array::from_fn(|j| 2.0 * (g2[r][0] * b[0][j] + g2[r][1] * b[1][j]) * f.s2[j])
    });
    // μ = √(2π/κ), κ = Σ_j c_j² s_j⁻²: G_c = 2 g_κ c s⁻², G_{s⁻²} = g_κ c², s⁻² = 1/s².
    let g_kappa = grad.mu * (-0.5 * st.splat.mu / st.kappa);
    let g_c: V3 = std::array::from_fn(|j| 2.0 * g_kappa * c[j] * f.inv_s2[j]);
    let g_scale: V3 = std::array::from_fn(|j| {
        let g_s2 = g2[0][0] * b[0][j] * b[0][j]
            + 2.0 * g2[0][1] * b[0][j] * b[1][j]
            + g2[1][1] * b[1][j] * b[1][j]
            - g_kappa * c[j] * c[j] * f.inv_s2[j] * f.inv_s2[j];
        2.0 * f.scale[j] * g_s2
    });
    // B = J A and c = Aᵀ r̂: G_A = Jᵀ G_B + r̂ G_cᵀ; then A = W R: G_R = Wᵀ G_A.
    let r = st.r_hat;
    let g_axes: M3 = std::array::from_fn(|i| {
        std::array::from_fn(|j| jac[0][i] * g_b[0][j] + jac[1][i] * g_b[1][j] + r[i] * g_c[j])
    });
    let g_quat = quat_backward(f.unit_quat, f.quat_norm, &mat_mul(&transpose(w), &g_axes));

    // Mean: through the projected centre, J(t) and r̂(t).
    let gm = grad.mean;
    let t = st.t;
    let mut g_t = [
        jac[0][0] * gm[0] + jac[1][0] * gm[1],
        jac[0][1] * gm[0] + jac[1][1] * gm[1],
        jac[0][2] * gm[0] + jac[1][2] * gm[1],
    ];
    if cam.projection == Projection::Cone {
        // G_J = G_B Aᵀ (2×3).
        let g_jac: [V3; 2] = [mat_vec(a, g_b[0]), mat_vec(a, g_b[1])];
        let iz = 1.0 / t[2];
        let iz2 = iz * iz;
        let (fx, fy) = (cam.fx, cam.fy);
        g_t[0] += g_jac[0][2] * (-fx * iz2);
        g_t[1] += g_jac[1][2] * (-fy * iz2);
        g_t[2] += g_jac[0][0] * (-fx * iz2)
            + g_jac[0][2] * (2.0 * fx * t[0] * iz2 * iz)
            + g_jac[1][1] * (-fy * iz2)
            + g_jac[1][2] * (2.0 * fy * t[1] * iz2 * iz);
        // r̂ = t/|t|: G_t += (I − r̂r̂ᵀ) G_r̂ / |t|, G_r̂ = A G_c.
        let g_r = mat_vec(a, g_c);
        let len = dot(t, t).sqrt();
        let along = dot(r, g_r);
        for k in 0..3 {
            g_t[k] += (g_r[k] - r[k] * along) / len;
        }
    }
    let geo = GeomGrad {
        mean: mat_t_vec(w, g_t),
        scale: g_scale,
        quat: g_quat,
    };
    Some((geo, *grad))
}

// ---------------------------------------------------------------------------------------------
// Exact line integral.

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

// ---------------------------------------------------------------------------------------------
// Voxelization.

/// A Gaussian prepared for voxelization: value at `x` is `ρ · exp(−½ q(x − mean))`.
#[derive(Clone, Copy, Debug)]
pub struct VoxelSplat {
    pub mean: V3,
    pub quad: Quad3,
    /// Half-extent of the cut-off ellipsoid's bounding box per world axis: `cutoff · √Σ_ii`.
    pub half_extent: V3,
}

pub fn voxel_splat(g: &GaussianGeom, cutoff: f64) -> Option<VoxelSplat> {
    let shape = shape3(g)?;
    let quad = Quad3::new(&shape.prec)?;
    let half_extent = [
        cutoff * shape.cov[0][0].sqrt(),
        cutoff * shape.cov[1][1].sqrt(),
        cutoff * shape.cov[2][2].sqrt(),
    ];
    half_extent
        .iter()
        .all(|v| v.is_finite())
        .then_some(VoxelSplat {
            mean: g.mean,
            quad,
            half_extent,
        })
}

/// Backward of the voxel value given the accumulated moments of `w = ∂L/∂value · ρ`-weighted
/// unit Gaussians: `sum_d = Σ w G d`, `sum_dd = Σ w G d dᵀ` (d = voxel centre − mean).
/// Returns the geometry gradient (mean, scale, quaternion).
pub fn voxel_backward(g: &GaussianGeom, sum_d: V3, sum_dd: &M3) -> GeomGrad {
    let Some(shape) = shape3(g) else {
        return GeomGrad::default();
    };
    // ∂G/∂mean = G · P d;  ∂G/∂P = −½ G d dᵀ.
    let g_mean = mat_vec(&shape.prec, sum_d);
    let mut g_prec = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            g_prec[i][j] = -0.5 * sum_dd[i][j];
        }
    }
    let (g_scale, g_quat) = shape3_backward(&shape, &[[0.0; 3]; 3], &g_prec);
    GeomGrad {
        mean: g_mean,
        scale: g_scale,
        quat: g_quat,
    }
}

#[cfg(test)]
mod tests;
