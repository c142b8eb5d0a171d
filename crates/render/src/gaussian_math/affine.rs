//! The affine (local-affine, EWA) splat of a Gaussian in one view, as R²-Gaussian renders it,
//! and its backward pass.

use super::*;

/// Per-view data of one Gaussian in the local-affine (EWA) approximation (with
/// `T = `[`F64x4`], of four, one per lane).
///
/// The image of the Gaussian is `ρ · μ · exp(−½ (x − mean)ᵀ Σ₂D⁻¹ (x − mean))` with `x` the pixel
/// centre in pixels, `μ = √(2π / (r̂ᵀ Σ_c⁻¹ r̂))` the exact line integral of the unit-density
/// Gaussian along the ray through its centre (`r̂` the unit direction from the source to the
/// centre, or the viewing axis for parallel beam).
#[derive(Clone, Copy, Debug)]
pub struct Splat<T = f64> {
    /// Projected centre (column, row) in pixels, screen offset included.
    pub mean: [T; 2],
    /// `Σ₂D⁻¹` in factored form.
    pub conic: Quad2<T>,
    /// `Σ₂D⁻¹` as a matrix `[a, b, c]` (for the backward pass).
    pub conic_mat: [T; 3],
    /// Integration factor μ (length units).
    pub mu: T,
    /// Half-extent of the cut-off ellipse's bounding box (pixels): `cutoff · √Σ₂D,ii`.
    pub half_extent: [T; 2],
}

impl Splat<F64x4> {
    /// The splat in lane `j`.
    #[inline(always)]
    pub fn lane(&self, j: usize) -> Splat {
        let at = |v: F64x4| v.0[j];
        Splat {
            mean: self.mean.map(at),
            conic: Quad2 {
                a: at(self.conic.a),
                beta: at(self.conic.beta),
                gamma: at(self.conic.gamma),
            },
            conic_mat: self.conic_mat.map(at),
            mu: at(self.mu),
            half_extent: self.half_extent.map(at),
        }
    }
}

/// Internals of [`splat`] kept for its backward pass.
///
/// Nothing 3×3 is multiplied out: with `A = W R` the Gaussian's axes in the camera frame,
/// `Σ₂D = B diag(s²) Bᵀ` with `B = J A` (2×3), and `κ = r̂ᵀ Σ_c⁻¹ r̂ = Σ_j c_j² / s_j²` with
/// `c = Aᵀ r̂`.
struct SplatState<T> {
    f: Factors<T>,
    /// `A = W R`.
    axes: [[T; 3]; 3],
    /// Rows of `B = J A`.
    b: [[T; 3]; 2],
    /// `c = Aᵀ r̂`.
    c: [T; 3],
    /// Centre in camera coordinates.
    t: [T; 3],
    /// 2×3 Jacobian of the projection at `t`.
    jac: [[T; 3]; 2],
    r_hat: [T; 3],
    kappa: T,
    splat: Splat<T>,
    /// The camera in every lane.
    cam: CameraLanes<T>,
}

/// A camera's numbers in every lane.
struct CameraLanes<T> {
    rotation: [[T; 3]; 3],
    translation: [T; 3],
    fx: T,
    fy: T,
    cx: T,
    cy: T,
}

impl<T: Real> CameraLanes<T> {
    #[inline(always)]
    fn new(cam: &Camera) -> Self {
        Self {
            rotation: cam.rotation.map(|r| r.map(T::splat)),
            translation: cam.translation.map(T::splat),
            fx: T::splat(cam.fx),
            fy: T::splat(cam.fy),
            cx: T::splat(cam.cx),
            cy: T::splat(cam.cy),
        }
    }
}

#[inline(always)]
fn splat_state<T: Real>(
    g: &GaussianGeom<T>,
    cam: &Camera,
    screen_offset: [T; 2],
    cutoff: f64,
    near: f64,
) -> (SplatState<T>, T::Mask) {
    let (f, mut ok) = factors_masked(g);
    let cl = CameraLanes::<T>::new(cam);
    let (zero, one) = (T::splat(0.0), T::splat(1.0));
    let axes = mat_mul(&cl.rotation, &f.rot);
    // [`Camera::to_camera`]: `W p + translation`, the same operations.
    let wp = mat_vec(&cl.rotation, g.mean);
    let t: [T; 3] = arr3(|i| wp[i] + cl.translation[i]);
    let (fx, fy) = (cl.fx, cl.fy);
    let (jac, r_hat, proj) = match cam.projection {
        Projection::Cone => {
            ok = ok & t[2].gt(T::splat(near));
            let iz = one / t[2];
            let jac = [
                [fx * iz, zero, -fx * t[0] * iz * iz],
                [zero, fy * iz, -fy * t[1] * iz * iz],
            ];
            let len = dot(t, t).sqrt();
            let r_hat = [t[0] / len, t[1] / len, t[2] / len];
            (jac, r_hat, [fx * t[0] * iz + cl.cx, fy * t[1] * iz + cl.cy])
        }
        Projection::Parallel => (
            [[fx, zero, zero], [zero, fy, zero]],
            [zero, zero, one],
            [fx * t[0] + cl.cx, fy * t[1] + cl.cy],
        ),
    };
    let c = mat_t_vec(&axes, r_hat);
    let kappa = c[0] * c[0] * f.inv_s2[0] + c[1] * c[1] * f.inv_s2[1] + c[2] * c[2] * f.inv_s2[2];
    let mu = (T::splat(2.0 * std::f64::consts::PI) / kappa).sqrt();
    ok = ok & kappa.gt(zero) & mu.is_finite();
    // Σ₂D = B diag(s²) Bᵀ, B = J A.
    let b = [mat_t_vec(&axes, jac[0]), mat_t_vec(&axes, jac[1])];
    let form = |p: [T; 3], q: [T; 3]| {
        p[0] * q[0] * f.s2[0] + p[1] * q[1] * f.s2[1] + p[2] * q[2] * f.s2[2]
    };
    let s00 = form(b[0], b[0]);
    let s01 = form(b[0], b[1]);
    let s11 = form(b[1], b[1]);
    let det = s00 * s11 - s01 * s01;
    ok = ok & det.is_finite() & det.gt(zero) & s00.gt(zero) & s11.gt(zero);
    let conic_mat = [s11 / det, -s01 / det, s00 / det];
    let (conic, conic_ok) =
        Quad2::new_masked([[conic_mat[0], conic_mat[1]], [conic_mat[1], conic_mat[2]]]);
    ok = ok & conic_ok;
    let mean = [proj[0] + screen_offset[0], proj[1] + screen_offset[1]];
    let cutoff = T::splat(cutoff);
    let half_extent = [cutoff * s00.sqrt(), cutoff * s11.sqrt()];
    for v in mean.into_iter().chain(half_extent) {
        ok = ok & v.is_finite();
    }
    let state = SplatState {
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
        cam: cl,
    };
    (state, ok)
}

/// The affine splat of a Gaussian in one view (or of four, in lanes), and whether it is valid:
/// not degenerate and, for cone beam, its centre in front of the near plane `z_c > near`.
#[inline(always)]
pub fn splat_masked<T: Real>(
    g: &GaussianGeom<T>,
    cam: &Camera,
    screen_offset: [T; 2],
    cutoff: f64,
    near: f64,
) -> (Splat<T>, T::Mask) {
    let (state, ok) = splat_state(g, cam, screen_offset, cutoff, near);
    (state.splat, ok)
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
    let (s, ok) = splat_masked(g, cam, screen_offset, cutoff, near);
    ok.then_some(s)
}

/// Loss gradients with respect to one splat's image-space quantities.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplatGrad<T = f64> {
    /// `∂L/∂mean` (pixels⁻¹ · loss).
    pub mean: [T; 2],
    /// `∂L/∂Σ₂D⁻¹` in the full-matrix convention `[[g_a, g_b], [g_b, g_c]]`, given as `[g_a, g_b, g_c]`.
    pub conic: [T; 3],
    pub mu: T,
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
    let (geo, grad, ok) = splat_backward_masked(g, cam, screen_offset, cutoff, near, grad);
    ok.then_some((geo, grad))
}

/// [`splat_backward_with`] for one Gaussian or four in lanes: the geometry gradient, the
/// [`SplatGrad`] it chained, and whether the splat is valid (where it is not, the values are
/// meaningless).
#[inline(always)]
pub fn splat_backward_masked<T: Real>(
    g: &GaussianGeom<T>,
    cam: &Camera,
    screen_offset: [T; 2],
    cutoff: f64,
    near: f64,
    grad: impl FnOnce(&Splat<T>) -> SplatGrad<T>,
) -> (GeomGrad<T>, SplatGrad<T>, T::Mask) {
    let (st, ok) = splat_state(g, cam, screen_offset, cutoff, near);
    let grad = grad(&st.splat);
    let cl = &st.cam;
    let w = &cl.rotation;
    let jac = &st.jac;
    let two = T::splat(2.0);
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
    let g2s = T::splat(0.5) * (g2[0][1] + g2[1][0]);
    let g2 = [[g2[0][0], g2s], [g2s, g2[1][1]]];
    let f = &st.f;
    let (a, b, c) = (&st.axes, &st.b, st.c);
    // Σ₂D = B D Bᵀ (D = diag(s²)): G_B = 2 G_Σ2D B D, G_D,j = Σ_ab G_ab B_aj B_bj.
    let g_b: [[T; 3]; 2] =
        arr2(|r| arr3(|j| two * (g2[r][0] * b[0][j] + g2[r][1] * b[1][j]) * f.s2[j]));
    // μ = √(2π/κ), κ = Σ_j c_j² s_j⁻²: G_c = 2 g_κ c s⁻², G_{s⁻²} = g_κ c², s⁻² = 1/s².
    let g_kappa = grad.mu * (T::splat(-0.5) * st.splat.mu / st.kappa);
    let g_c: [T; 3] = arr3(|j| two * g_kappa * c[j] * f.inv_s2[j]);
    let g_scale: [T; 3] = arr3(|j| {
        let g_s2 = g2[0][0] * b[0][j] * b[0][j]
            + two * g2[0][1] * b[0][j] * b[1][j]
            + g2[1][1] * b[1][j] * b[1][j]
            - g_kappa * c[j] * c[j] * f.inv_s2[j] * f.inv_s2[j];
        two * f.scale[j] * g_s2
    });
    // B = J A and c = Aᵀ r̂: G_A = Jᵀ G_B + r̂ G_cᵀ; then A = W R: G_R = Wᵀ G_A.
    let r = st.r_hat;
    let g_axes: [[T; 3]; 3] =
        arr3(|i| arr3(|j| jac[0][i] * g_b[0][j] + jac[1][i] * g_b[1][j] + r[i] * g_c[j]));
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
        let g_jac: [[T; 3]; 2] = [mat_vec(a, g_b[0]), mat_vec(a, g_b[1])];
        let iz = T::splat(1.0) / t[2];
        let iz2 = iz * iz;
        let (fx, fy) = (cl.fx, cl.fy);
        g_t[0] = g_t[0] + g_jac[0][2] * (-fx * iz2);
        g_t[1] = g_t[1] + g_jac[1][2] * (-fy * iz2);
        g_t[2] = g_t[2]
            + (g_jac[0][0] * (-fx * iz2)
                + g_jac[0][2] * (two * fx * t[0] * iz2 * iz)
                + g_jac[1][1] * (-fy * iz2)
                + g_jac[1][2] * (two * fy * t[1] * iz2 * iz));
        // r̂ = t/|t|: G_t += (I − r̂r̂ᵀ) G_r̂ / |t|, G_r̂ = A G_c.
        let g_r = mat_vec(a, g_c);
        let len = dot(t, t).sqrt();
        let along = dot(r, g_r);
        for k in 0..3 {
            g_t[k] = g_t[k] + (g_r[k] - r[k] * along) / len;
        }
    }
    let geo = GeomGrad {
        mean: mat_t_vec(w, g_t),
        scale: g_scale,
        quat: g_quat,
    };
    (geo, grad, ok)
}
