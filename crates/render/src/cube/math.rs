//! Per-Gaussian math of the CubeCL kernels, in f32: the port of [`crate::gaussian_math`]'s
//! affine splat, voxel shape and their backward passes (same formulas, same degenerate-case
//! rules, so the CPU and GPU kernels agree to f32 rounding).
//!
//! Vectors and matrices live in local `Array<f32>`s (row-major 3×3). A function that can reject
//! a Gaussian returns `false` and leaves its outputs unspecified.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

/// Length of a packed camera record (see [`super::pack_cameras`]).
pub const CAM_WIDTH: usize = 20;
/// Camera record fields: world→camera rotation (9, row-major), translation (3), then these.
pub const CAM_FX: usize = 12;
pub const CAM_FY: usize = 13;
pub const CAM_CX: usize = 14;
pub const CAM_CY: usize = 15;
pub const CAM_SDD: usize = 16;
/// 1 for cone beam, 0 for parallel beam.
pub const CAM_CONE: usize = 17;

/// Width of the splat state array filled by [`splat_state`].
pub const ST_LEN: usize = 64;
// Splat state layout.
pub const ST_ROT: usize = 0; // R (9)
pub const ST_QUAT: usize = 9; // unit quaternion (4)
pub const ST_QNORM: usize = 13; // |q|
pub const ST_SCALE: usize = 14; // s (3)
pub const ST_S2: usize = 17; // s² (3)
pub const ST_INV_S2: usize = 20; // s⁻² (3)
pub const ST_AXES: usize = 23; // A = W R (9)
pub const ST_T: usize = 32; // centre in camera coordinates (3)
pub const ST_JAC: usize = 35; // J, 2×3 (6)
pub const ST_RHAT: usize = 41; // r̂ (3)
pub const ST_C: usize = 44; // c = Aᵀ r̂ (3)
pub const ST_B: usize = 47; // B = J A, 2×3 (6)
pub const ST_KAPPA: usize = 53;
pub const ST_MU: usize = 54;
pub const ST_CONIC: usize = 55; // Σ₂D⁻¹ as [a, b, c] (3)
pub const ST_MEAN: usize = 58; // projected centre + screen offset (2)
pub const ST_HALF: usize = 60; // half-extent of the cut-off box (2)

/// Finite (false for ±∞ and NaN).
#[cube]
pub fn finite(x: f32) -> bool {
    f32::abs(x) <= 3.0e38f32
}

/// Fill `st[ST_ROT..]`, `st[ST_QUAT..]`, `ST_QNORM`, `ST_SCALE`, `ST_S2`, `ST_INV_S2` for Gaussian
/// `i`; `false` if it is degenerate (zero or non-finite quaternion, non-positive or non-finite
/// scale, non-finite mean).
#[cube]
pub fn factors(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    i: usize,
    st: &mut Array<f32>,
) -> bool {
    let mut ok = true;
    let q0 = rotations[4 * i];
    let q1 = rotations[4 * i + 1];
    let q2 = rotations[4 * i + 2];
    let q3 = rotations[4 * i + 3];
    let n = f32::sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3);
    if !(finite(n) && n > 1.0e-12f32) {
        ok = false;
    }
    for a in 0..3usize {
        if !finite(means[3 * i + a]) {
            ok = false;
        }
        let s = scales[3 * i + a];
        let s2 = s * s;
        let inv = 1.0f32 / s2;
        if !(finite(s) && s > 0.0f32 && finite(s2) && s2 > 0.0f32 && finite(inv) && inv > 0.0f32) {
            ok = false;
        }
        st[ST_SCALE + a] = s;
        st[ST_S2 + a] = s2;
        st[ST_INV_S2 + a] = inv;
    }
    let w = q0 / n;
    let x = q1 / n;
    let y = q2 / n;
    let z = q3 / n;
    st[ST_QUAT] = w;
    st[ST_QUAT + 1] = x;
    st[ST_QUAT + 2] = y;
    st[ST_QUAT + 3] = z;
    st[ST_QNORM] = n;
    st[ST_ROT] = 1.0f32 - 2.0f32 * (y * y + z * z);
    st[ST_ROT + 1] = 2.0f32 * (x * y - w * z);
    st[ST_ROT + 2] = 2.0f32 * (x * z + w * y);
    st[ST_ROT + 3] = 2.0f32 * (x * y + w * z);
    st[ST_ROT + 4] = 1.0f32 - 2.0f32 * (x * x + z * z);
    st[ST_ROT + 5] = 2.0f32 * (y * z - w * x);
    st[ST_ROT + 6] = 2.0f32 * (x * z - w * y);
    st[ST_ROT + 7] = 2.0f32 * (y * z + w * x);
    st[ST_ROT + 8] = 1.0f32 - 2.0f32 * (x * x + y * y);
    ok
}

/// `∂L/∂q` of the raw quaternion from `G_R = ∂L/∂R` (`g_rot`, row-major), written to
/// `out[0..4]`; `st` holds the factors.
#[cube]
pub fn quat_backward(st: &Array<f32>, g: &Array<f32>, out: &mut Array<f32>) {
    let w = st[ST_QUAT];
    let x = st[ST_QUAT + 1];
    let y = st[ST_QUAT + 2];
    let z = st[ST_QUAT + 3];
    let gw = 2.0f32 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
    let gx = 2.0f32
        * (y * g[1] + z * g[2] + y * g[3] - 2.0f32 * x * g[4] - w * g[5] + z * g[6] + w * g[7]
            - 2.0f32 * x * g[8]);
    let gy = 2.0f32
        * (-2.0f32 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7]
            - 2.0f32 * y * g[8]);
    let gz = 2.0f32
        * (-2.0f32 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2.0f32 * z * g[4]
            + y * g[5]
            + x * g[6]
            + y * g[7]);
    let radial = gw * w + gx * x + gy * y + gz * z;
    let n = st[ST_QNORM];
    out[0] = (gw - w * radial) / n;
    out[1] = (gx - x * radial) / n;
    out[2] = (gy - y * radial) / n;
    out[3] = (gz - z * radial) / n;
}

/// The affine splat of Gaussian `i` in view `v` (cameras packed `[V, CAM_WIDTH]`, screen
/// offsets `[V, K, 2]`), as [`crate::gaussian_math::splat`]: fills the whole state `st`;
/// `false` if it is degenerate or (cone beam) not in front of the near plane.
///
/// `det Σ₂D` is summed from the 2×2 minors of `B` (Cauchy–Binet), free of the cancellation of
/// `s00 s11 − s01²` in f32.
#[cube]
#[allow(clippy::too_many_arguments)]
pub fn splat_state(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    screen: &Tensor<f32>,
    cams: &Tensor<f32>,
    i: usize,
    v: usize,
    k: usize,
    cutoff: f32,
    near_fraction: f32,
    st: &mut Array<f32>,
) -> bool {
    let mut ok = factors(means, scales, rotations, i, st);
    let cb = v * CAM_WIDTH;
    // A = W R and t = W p + T.
    for r in 0..3usize {
        for c in 0..3usize {
            st[ST_AXES + 3 * r + c] = cams[cb + 3 * r] * st[ST_ROT + c]
                + cams[cb + 3 * r + 1] * st[ST_ROT + 3 + c]
                + cams[cb + 3 * r + 2] * st[ST_ROT + 6 + c];
        }
        st[ST_T + r] = cams[cb + 3 * r] * means[3 * i]
            + cams[cb + 3 * r + 1] * means[3 * i + 1]
            + cams[cb + 3 * r + 2] * means[3 * i + 2]
            + cams[cb + 9 + r];
    }
    let fx = cams[cb + CAM_FX];
    let fy = cams[cb + CAM_FY];
    let t0 = st[ST_T];
    let t1 = st[ST_T + 1];
    let t2 = st[ST_T + 2];
    let mut px = fx * t0 + cams[cb + CAM_CX];
    let mut py = fy * t1 + cams[cb + CAM_CY];
    st[ST_JAC] = fx;
    st[ST_JAC + 1] = 0.0f32;
    st[ST_JAC + 2] = 0.0f32;
    st[ST_JAC + 3] = 0.0f32;
    st[ST_JAC + 4] = fy;
    st[ST_JAC + 5] = 0.0f32;
    st[ST_RHAT] = 0.0f32;
    st[ST_RHAT + 1] = 0.0f32;
    st[ST_RHAT + 2] = 1.0f32;
    if cams[cb + CAM_CONE] > 0.5f32 {
        let near = near_fraction * cams[cb + CAM_SDD];
        if !(t2 > near) {
            ok = false;
        }
        let iz = 1.0f32 / t2;
        st[ST_JAC] = fx * iz;
        st[ST_JAC + 2] = -fx * t0 * iz * iz;
        st[ST_JAC + 4] = fy * iz;
        st[ST_JAC + 5] = -fy * t1 * iz * iz;
        let len = f32::sqrt(t0 * t0 + t1 * t1 + t2 * t2);
        st[ST_RHAT] = t0 / len;
        st[ST_RHAT + 1] = t1 / len;
        st[ST_RHAT + 2] = t2 / len;
        px = fx * t0 * iz + cams[cb + CAM_CX];
        py = fy * t1 * iz + cams[cb + CAM_CY];
    }
    // c = Aᵀ r̂, B rows = Aᵀ J rows.
    let mut kappa = 0.0f32;
    for j in 0..3usize {
        let mut c = 0.0f32;
        let mut b0 = 0.0f32;
        let mut b1 = 0.0f32;
        for r in 0..3usize {
            let a = st[ST_AXES + 3 * r + j];
            c += a * st[ST_RHAT + r];
            b0 += a * st[ST_JAC + r];
            b1 += a * st[ST_JAC + 3 + r];
        }
        st[ST_C + j] = c;
        st[ST_B + j] = b0;
        st[ST_B + 3 + j] = b1;
        kappa += c * c * st[ST_INV_S2 + j];
    }
    let mu = f32::sqrt(6.283_185_5f32 / kappa);
    if !(kappa > 0.0f32 && finite(mu)) {
        ok = false;
    }
    st[ST_KAPPA] = kappa;
    st[ST_MU] = mu;
    let mut s00 = 0.0f32;
    let mut s01 = 0.0f32;
    let mut s11 = 0.0f32;
    for j in 0..3usize {
        let b0 = st[ST_B + j];
        let b1 = st[ST_B + 3 + j];
        let s2 = st[ST_S2 + j];
        s00 += b0 * b0 * s2;
        s01 += b0 * b1 * s2;
        s11 += b1 * b1 * s2;
    }
    // det = Σ_{j<l} s_j² s_l² (b0_j b1_l − b0_l b1_j)².
    let m01 = st[ST_B] * st[ST_B + 4] - st[ST_B + 1] * st[ST_B + 3];
    let m02 = st[ST_B] * st[ST_B + 5] - st[ST_B + 2] * st[ST_B + 3];
    let m12 = st[ST_B + 1] * st[ST_B + 5] - st[ST_B + 2] * st[ST_B + 4];
    let det = st[ST_S2] * st[ST_S2 + 1] * m01 * m01
        + st[ST_S2] * st[ST_S2 + 2] * m02 * m02
        + st[ST_S2 + 1] * st[ST_S2 + 2] * m12 * m12;
    if !(finite(det) && det > 0.0f32 && s00 > 0.0f32 && s11 > 0.0f32) {
        ok = false;
    }
    let ca = s11 / det;
    let cb2 = -s01 / det;
    let cc = s00 / det;
    st[ST_CONIC] = ca;
    st[ST_CONIC + 1] = cb2;
    st[ST_CONIC + 2] = cc;
    let o = 2 * (v * k + i);
    st[ST_MEAN] = px + screen[o];
    st[ST_MEAN + 1] = py + screen[o + 1];
    st[ST_HALF] = cutoff * f32::sqrt(s00);
    st[ST_HALF + 1] = cutoff * f32::sqrt(s11);
    for a in 0..2usize {
        if !(finite(st[ST_MEAN + a]) && finite(st[ST_HALF + a])) {
            ok = false;
        }
    }
    ok
}

/// Chain the image-space gradient of a splat (`grad_mean` (2), `grad_conic` `[g_a, g_b, g_c]`
/// (3), `grad_mu`) to the Gaussian's geometry, as [`crate::gaussian_math::splat_backward_with`]:
/// `out = [∂mean (3), ∂scale (3), ∂quat (4)]`. `st` is the state of [`splat_state`] for the
/// same Gaussian and view; `cams`/`v` give the view's rotation. `tmp` is scratch of length ≥ 32.
#[cube]
#[allow(clippy::too_many_arguments)]
pub fn splat_backward(
    st: &Array<f32>,
    cams: &Tensor<f32>,
    v: usize,
    grad_mean: &Array<f32>,
    grad_conic: &Array<f32>,
    grad_mu: f32,
    tmp: &mut Array<f32>,
    out: &mut Array<f32>,
) {
    let cb = v * CAM_WIDTH;
    let ca = st[ST_CONIC];
    let cbb = st[ST_CONIC + 1];
    let cc = st[ST_CONIC + 2];
    let ga = grad_conic[0];
    let gb = grad_conic[1];
    let gc = grad_conic[2];
    // G_Σ2D = −C G_C C (symmetrised).
    let cg00 = ca * ga + cbb * gb;
    let cg01 = ca * gb + cbb * gc;
    let cg10 = cbb * ga + cc * gb;
    let cg11 = cbb * gb + cc * gc;
    let g00 = -(cg00 * ca + cg01 * cbb);
    let g01a = -(cg00 * cbb + cg01 * cc);
    let g10a = -(cg10 * ca + cg11 * cbb);
    let g11 = -(cg10 * cbb + cg11 * cc);
    let g01 = 0.5f32 * (g01a + g10a);
    let mu = st[ST_MU];
    let kappa = st[ST_KAPPA];
    let g_kappa = grad_mu * (-0.5f32 * mu / kappa);
    // tmp[0..6] = G_B (2×3), tmp[6..9] = G_c, out scale.
    for j in 0..3usize {
        let b0 = st[ST_B + j];
        let b1 = st[ST_B + 3 + j];
        let s2 = st[ST_S2 + j];
        let inv = st[ST_INV_S2 + j];
        let c = st[ST_C + j];
        tmp[j] = 2.0f32 * (g00 * b0 + g01 * b1) * s2;
        tmp[3 + j] = 2.0f32 * (g01 * b0 + g11 * b1) * s2;
        tmp[6 + j] = 2.0f32 * g_kappa * c * inv;
        let g_s2 =
            g00 * b0 * b0 + 2.0f32 * g01 * b0 * b1 + g11 * b1 * b1 - g_kappa * c * c * inv * inv;
        out[3 + j] = 2.0f32 * st[ST_SCALE + j] * g_s2;
    }
    // G_A = Jᵀ G_B + r̂ G_cᵀ (tmp[9..18]); G_R = Wᵀ G_A (tmp[18..27]).
    for r in 0..3usize {
        for j in 0..3usize {
            tmp[9 + 3 * r + j] = st[ST_JAC + r] * tmp[j]
                + st[ST_JAC + 3 + r] * tmp[3 + j]
                + st[ST_RHAT + r] * tmp[6 + j];
        }
    }
    for r in 0..3usize {
        for j in 0..3usize {
            tmp[18 + 3 * r + j] = cams[cb + r] * tmp[9 + j]
                + cams[cb + 3 + r] * tmp[12 + j]
                + cams[cb + 6 + r] * tmp[15 + j];
        }
    }
    let mut g_rot = Array::<f32>::new(9usize);
    for e in 0..9usize {
        g_rot[e] = tmp[18 + e];
    }
    let mut g_quat = Array::<f32>::new(4usize);
    quat_backward(st, &g_rot, &mut g_quat);
    for e in 0..4usize {
        out[6 + e] = g_quat[e];
    }
    // Mean: through the projected centre, J(t) and r̂(t).
    let gm0 = grad_mean[0];
    let gm1 = grad_mean[1];
    let mut gt0 = st[ST_JAC] * gm0 + st[ST_JAC + 3] * gm1;
    let mut gt1 = st[ST_JAC + 1] * gm0 + st[ST_JAC + 4] * gm1;
    let mut gt2 = st[ST_JAC + 2] * gm0 + st[ST_JAC + 5] * gm1;
    if cams[cb + CAM_CONE] > 0.5f32 {
        let t0 = st[ST_T];
        let t1 = st[ST_T + 1];
        let t2 = st[ST_T + 2];
        // G_J = G_B Aᵀ (2×3): row r, column i = Σ_j G_B[r][j] A[i][j].
        let mut gj00 = 0.0f32;
        let mut gj02 = 0.0f32;
        let mut gj11 = 0.0f32;
        let mut gj12 = 0.0f32;
        for j in 0..3usize {
            gj00 += tmp[j] * st[ST_AXES + j];
            gj02 += tmp[j] * st[ST_AXES + 6 + j];
            gj11 += tmp[3 + j] * st[ST_AXES + 3 + j];
            gj12 += tmp[3 + j] * st[ST_AXES + 6 + j];
        }
        let fx = cams[cb + CAM_FX];
        let fy = cams[cb + CAM_FY];
        let iz = 1.0f32 / t2;
        let iz2 = iz * iz;
        gt0 += gj02 * (-fx * iz2);
        gt1 += gj12 * (-fy * iz2);
        gt2 += gj00 * (-fx * iz2)
            + gj02 * (2.0f32 * fx * t0 * iz2 * iz)
            + gj11 * (-fy * iz2)
            + gj12 * (2.0f32 * fy * t1 * iz2 * iz);
        // r̂ = t/|t|: G_t += (I − r̂r̂ᵀ) G_r̂ / |t|, G_r̂ = A G_c.
        let mut gr = Array::<f32>::new(3usize);
        for r in 0..3usize {
            gr[r] = st[ST_AXES + 3 * r] * tmp[6]
                + st[ST_AXES + 3 * r + 1] * tmp[7]
                + st[ST_AXES + 3 * r + 2] * tmp[8];
        }
        let len = f32::sqrt(t0 * t0 + t1 * t1 + t2 * t2);
        let along = st[ST_RHAT] * gr[0] + st[ST_RHAT + 1] * gr[1] + st[ST_RHAT + 2] * gr[2];
        gt0 += (gr[0] - st[ST_RHAT] * along) / len;
        gt1 += (gr[1] - st[ST_RHAT + 1] * along) / len;
        gt2 += (gr[2] - st[ST_RHAT + 2] * along) / len;
    }
    // ∂mean = Wᵀ G_t.
    for a in 0..3usize {
        out[a] = cams[cb + a] * gt0 + cams[cb + 3 + a] * gt1 + cams[cb + 6 + a] * gt2;
    }
}

/// `Σ_aa`, the covariance's diagonal entry on world axis `a`, of the Gaussian whose factors
/// [`factors`] put in `st`: `Σ_j R_aj² s_j²`.
#[cube]
pub fn variance(st: &Array<f32>, a: usize) -> f32 {
    let mut v = 0.0f32;
    for j in 0..3usize {
        let r = st[ST_ROT + 3 * a + j];
        v += r * r * st[ST_S2 + j];
    }
    v
}

/// Cell range `[lo, hi)` of the inclusive index interval `[first, last]` on a grid of `n` cells,
/// as [`crate::cpu::tiles::tile_span`], written to `out[o]`, `out[o + 1]` (as f32, exact below
/// 2²⁴); `[0, 0)` if it misses the grid or is NaN.
#[cube]
pub fn cell_span(first: f32, last: f32, n: u32, out: &mut Array<f32>, o: usize) {
    let lo = f32::max(f32::ceil(first), 0.0f32);
    let hi = f32::min(f32::floor(last), f32::cast_from(n) - 1.0f32);
    let mut a = 0.0f32;
    let mut b = 0.0f32;
    if first <= last && lo <= hi {
        a = lo;
        b = hi + 1.0f32;
    }
    out[o] = a;
    out[o + 1] = b;
}

// ---------------------------------------------------------------------------------------------
// Exact line integral (the f32 port of `gaussian_math::line_integral`, reformulated so that no
// step subtracts two large coordinates).

/// Width of an exact-mode prepared record: `[x, y, z]` the camera-frame centre with the screen
/// offset applied, the camera-frame axes `A_j = (W R)_j` (3 × 3, row `j`), the scales `s_j` (3),
/// then the pixel box `[x0, x1, y0, y1]`.
pub const EX_WIDTH: usize = 19;
/// Offset of the axes `A_j` in an exact record.
pub const EX_AXES: usize = 3;
/// Offset of the scales in an exact record.
pub const EX_SCALE: usize = 12;
/// Offset of the pixel box in an exact record.
pub const EX_BOX: usize = 15;

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

/// Width of the per-pixel ray state of [`exact_ray`].
pub const RAY_LEN: usize = 28;
// Ray state layout.
pub const RAY_D: usize = 0; // ray direction D, z component 1 (3)
pub const RAY_W: usize = 3; // offset w at the centre's depth (3, z = 0)
pub const RAY_C: usize = 6; // c = w × D (3)
pub const RAY_AD: usize = 9; // A_j · D (3)
pub const RAY_AW: usize = 12; // A_j · w (3)
pub const RAY_AC: usize = 15; // A_j · c (3)
pub const RAY_A: usize = 18; // a = Dᵀ Σ_c⁻¹ D = Σ_j (A_j · D)² / s_j²
pub const RAY_B: usize = 19; // b = Dᵀ Σ_c⁻¹ w
pub const RAY_Q: usize = 20; // Q = a · q = Σ_j (A_j · c)² / (s_k s_l)²
pub const RAY_S: usize = 21; // √(2a)
pub const RAY_U0: usize = 22; // erf argument at the segment start
pub const RAY_U1: usize = 23; // erf argument at the segment end
pub const RAY_BASE: usize = 24; // |D| √(2π/a) e^{−q/2}
pub const RAY_T: usize = 25; // segment fraction
pub const RAY_VALUE: usize = 26; // the integral, RAY_BASE · RAY_T

/// The exact integral of the unit-density Gaussian of exact record `r` along the ray of pixel
/// `(col, row)` of view `v`, with its intermediate terms in `ray`; `false` if the ray passes
/// beyond the cut-off (`q > cut2`) or the terms are degenerate.
///
/// The ray is parametrised by its depth `τ` (cone: points `τ D` with `D = ((col − cx)/fx,
/// (row − cy)/fy, 1)`; parallel: `(L, τ)` with `D = (0, 0, 1)`), shifted to the centre's depth,
/// `σ = τ − z_c`: the offset from the centre is `σ D + w`, `w = (z_c L − p_xy, 0)` (cone) or
/// `(L − p_xy, 0)` (parallel), `L` the pixel's lateral coordinate. The segment runs from the
/// source (cone) or start plane (`σ₀ = −z_c`) to the detector (`σ₁ = sdd − z_c`), and
/// `∫ e^{−½ q(σ)} |D| dσ = |D| √(2π/a) e^{−q/2} ½[erf(u₁) − erf(u₀)]`, `u_i = (a σ_i + b)/√(2a)`.
///
/// The line's Mahalanobis distance is taken in cofactor form, `q = |Σ^{-½}(w × D)|²`-like:
/// `q = Σ_j (A_j · (w × D))² / (s_k s_l)² / a` ({j, k, l} = {0, 1, 2}), the 3D analogue of the
/// affine splat's Cauchy–Binet determinant. It never forms a thin axis' coordinate of a far
/// offset, so a sheet crossed far from its centre keeps its accuracy in f32 (the form
/// `|w|² − b²/a` loses `ε · |w| / s_min`).
#[cube]
#[allow(clippy::too_many_arguments)]
pub fn exact_ray(
    rec: &Tensor<f32>,
    r: usize,
    cams: &Tensor<f32>,
    v: usize,
    col: f32,
    row: f32,
    cut2: f32,
    ray: &mut Array<f32>,
) -> bool {
    let cb = v * CAM_WIDTH;
    let lx = (col - cams[cb + CAM_CX]) / cams[cb + CAM_FX];
    let ly = (row - cams[cb + CAM_CY]) / cams[cb + CAM_FY];
    let z = rec[r + 2];
    let mut dlen = 1.0f32;
    ray[RAY_D + 2] = 1.0f32;
    ray[RAY_W + 2] = 0.0f32;
    if cams[cb + CAM_CONE] > 0.5f32 {
        ray[RAY_D] = lx;
        ray[RAY_D + 1] = ly;
        ray[RAY_W] = z * lx - rec[r];
        ray[RAY_W + 1] = z * ly - rec[r + 1];
        dlen = f32::sqrt(lx * lx + ly * ly + 1.0f32);
    } else {
        ray[RAY_D] = 0.0f32;
        ray[RAY_D + 1] = 0.0f32;
        ray[RAY_W] = lx - rec[r];
        ray[RAY_W + 1] = ly - rec[r + 1];
    }
    // c = w × D with w_z = 0, D_z = 1.
    ray[RAY_C] = ray[RAY_W + 1];
    ray[RAY_C + 1] = -ray[RAY_W];
    ray[RAY_C + 2] = ray[RAY_W] * ray[RAY_D + 1] - ray[RAY_W + 1] * ray[RAY_D];
    let mut a = 0.0f32;
    let mut b = 0.0f32;
    let mut qq = 0.0f32;
    for j in 0..3usize {
        let o = r + EX_AXES + 3 * j;
        let ad = rec[o] * ray[RAY_D] + rec[o + 1] * ray[RAY_D + 1] + rec[o + 2];
        let aw = rec[o] * ray[RAY_W] + rec[o + 1] * ray[RAY_W + 1];
        let ac = rec[o] * ray[RAY_C] + rec[o + 1] * ray[RAY_C + 1] + rec[o + 2] * ray[RAY_C + 2];
        ray[RAY_AD + j] = ad;
        ray[RAY_AW + j] = aw;
        ray[RAY_AC + j] = ac;
        let sj = rec[r + EX_SCALE + j];
        let ed = ad / sj;
        a += ed * ed;
        b += ed * (aw / sj);
        let n = ac / (rec[r + EX_SCALE + (j + 1) % 3] * rec[r + EX_SCALE + (j + 2) % 3]);
        qq += n * n;
    }
    let q = qq / a;
    let mut ok = a > 0.0f32 && finite(a) && finite(b) && finite(qq) && q <= cut2;
    let s = f32::sqrt(2.0f32 * a);
    let sdd = cams[cb + CAM_SDD];
    let u0 = (b - a * z) / s;
    let u1 = (a * (sdd - z) + b) / s;
    let base = dlen * f32::sqrt(6.283_185_5f32 / a) * f32::exp(-0.5f32 * q);
    let t = segment_fraction(u0, u1);
    let value = base * t;
    if !(finite(value) && finite(base)) {
        ok = false;
    }
    ray[RAY_A] = a;
    ray[RAY_B] = b;
    ray[RAY_Q] = qq;
    ray[RAY_S] = s;
    ray[RAY_U0] = u0;
    ray[RAY_U1] = u1;
    ray[RAY_BASE] = base;
    ray[RAY_T] = t;
    ray[RAY_VALUE] = value;
    ok
}
