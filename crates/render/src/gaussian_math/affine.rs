//! The affine (local-affine, EWA) splat of a Gaussian in one view, as R²-Gaussian renders it,
//! and its backward pass.

use super::*;

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
