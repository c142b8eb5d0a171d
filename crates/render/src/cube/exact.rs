//! Exact-mode projection kernels: the per-(view, Gaussian) [`ExactRecord`] and the per-Gaussian
//! backward of the closed-form ray integral ([`super::math::exact_ray`]). The forward pass is
//! [`super::project::forward_kernel`] with `exact` set.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::math::{Ray, RayGaussian, exact_ray, factors, quat_backward};
use super::types::{
    GaussianBuffers, Mat3, Params, ProjectUniforms, Rect, Vec3, View, cell_span, densities_finite,
    finite, offset,
};

/// Floats per [`ExactRecord`].
pub const EXACT_WIDTH: usize = 19;
/// Where an [`ExactRecord`] keeps its pixel box.
pub const EXACT_BOX: usize = 15;

/// A Gaussian prepared for exact ray integrals in one view: `[centre (3), axes A_j (3 × 3, row
/// j), scales (3), pixel box (4)]`.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct ExactRecord {
    pub g: RayGaussian,
    pub bbox: Rect,
}

#[cube]
impl ExactRecord {
    pub fn culled() -> ExactRecord {
        ExactRecord {
            g: RayGaussian {
                centre: Vec3::zero(),
                axes: Mat3::zero(),
                scale: Vec3::zero(),
            },
            bbox: Rect::empty(),
        }
    }

    pub fn load(t: &Tensor<f32>, o: usize) -> ExactRecord {
        ExactRecord {
            g: RayGaussian {
                centre: Vec3::load(t, o),
                axes: Mat3::load(t, o + 3),
                scale: Vec3::load(t, o + 12),
            },
            bbox: Rect::load(t, o + EXACT_BOX),
        }
    }

    pub fn store(self, t: &mut Tensor<f32>, o: usize) {
        self.g.centre.store(t, o);
        self.g.axes.store(t, o + 3);
        self.g.scale.store(t, o + 12);
        self.bbox.store(t, o + EXACT_BOX);
    }
}

/// Exact-mode preparation: per (view, Gaussian), an [`ExactRecord`] (the camera-frame centre
/// with the screen offset applied, the camera-frame axes and scales, the pixel box), as the
/// CPU's `exact_splat`: the cut-off box `centre ± cutoff·√diag Σ_c` must overlap
/// `0 ≤ z ≤ sdd`; its projected corners bound the pixel box (cone: the whole detector if the box
/// reaches the source plane). Zeros if culled.
#[cube(launch)]
pub fn prepare_exact_kernel(
    gaussians: &GaussianBuffers,
    screen: &Tensor<f32>,
    cams: &Tensor<f32>,
    out: &mut Tensor<f32>,
    uniforms: &ProjectUniforms,
    #[comptime] m: usize,
) {
    let idx = ABSOLUTE_POS;
    let kk = uniforms.k as usize;
    if idx >= kk * uniforms.n_views as usize {
        terminate!();
    }
    let cutoff = uniforms.cutoff;
    let v = idx / kk;
    let i = idx % kk;
    let mut rec = ExactRecord::culled();
    let p = Params::load(gaussians, i);
    let f = factors(p);
    if densities_finite(&gaussians.densities, i, m) && f.ok {
        let cam = View::load(cams, v);
        let t = cam.to_camera(p.mean);
        let z = t.z;
        let (ox, oy) = offset(screen, v, kk, i);
        let mut x = t.x + ox / cam.fx;
        let mut y = t.y + oy / cam.fy;
        if cam.cone {
            x = t.x + ox * z / cam.fx;
            y = t.y + oy * z / cam.fy;
        }
        // W R; the camera-frame covariance diagonal Σ_j (W R)_rj² s_j².
        let wr = cam.rot.mul(f.rot);
        let h = Vec3::new(
            cutoff * f32::sqrt(wr.r0.mul(wr.r0).dot(f.s2)),
            cutoff * f32::sqrt(wr.r1.mul(wr.r1).dot(f.s2)),
            cutoff * f32::sqrt(wr.r2.mul(wr.r2).dot(f.s2)),
        );
        let mut good = h.is_finite() && finite(x) && finite(y) && finite(z);
        let z_lo = z - h.z;
        let z_hi = z + h.z;
        if z_hi < 0.0f32 || z_lo > cam.sdd {
            good = false;
        }
        let mut bb = Rect {
            x0: cam.fx * (x - h.x) + cam.cx,
            x1: cam.fx * (x + h.x) + cam.cx,
            y0: cam.fy * (y - h.y) + cam.cy,
            y1: cam.fy * (y + h.y) + cam.cy,
        };
        if cam.cone {
            let z_min = f32::max(cam.sdd * 1.0e-9f32, 1.0e-30f32);
            // ±3e38 stands for ±∞ (no infinity literal in WGSL): the whole detector.
            if z_lo <= z_min {
                bb = Rect {
                    x0: -3.0e38f32,
                    x1: 3.0e38f32,
                    y0: -3.0e38f32,
                    y1: 3.0e38f32,
                };
            } else {
                let mut u0 = 3.0e38f32;
                let mut u1 = f32::new(-3.0e38f32);
                let mut w0 = 3.0e38f32;
                let mut w1 = f32::new(-3.0e38f32);
                for corner in 0..8u32 {
                    let sx = select((corner & 1u32) == 0u32, -1.0f32, 1.0f32);
                    let sy = select((corner & 2u32) == 0u32, -1.0f32, 1.0f32);
                    let zz = select((corner & 4u32) == 0u32, z_lo, z_hi);
                    let u = cam.fx * (x + sx * h.x) / zz + cam.cx;
                    let w = cam.fy * (y + sy * h.y) / zz + cam.cy;
                    u0 = f32::min(u0, u);
                    u1 = f32::max(u1, u);
                    w0 = f32::min(w0, w);
                    w1 = f32::max(w1, w);
                }
                bb = Rect {
                    x0: u0,
                    x1: u1,
                    y0: w0,
                    y1: w1,
                };
            }
        }
        let (x0, x1) = cell_span(bb.x0, bb.x1, uniforms.cols);
        let (y0, y1) = cell_span(bb.y0, bb.y1, uniforms.rows);
        let span = Rect { x0, x1, y0, y1 };
        if span.is_empty() {
            good = false;
        }
        if good {
            rec = ExactRecord {
                g: RayGaussian {
                    centre: Vec3::new(x, y, z),
                    // Row j is the Gaussian's axis j in the camera frame: column j of W R.
                    axes: wr.transpose(),
                    scale: f.scale,
                },
                bbox: span,
            };
        }
    }
    rec.store(out, idx * EXACT_WIDTH);
}

/// The per-pixel derivatives of the exact backward, summed over a footprint: with respect to the
/// record's axes `A_j` (rows), scales, the offset `w` (x, y), `Σ ∂w · D_xy`, and the segment
/// ends `σ₀ = −z_c`, `σ₁ = sdd − z_c`.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
struct ExactSums {
    axes: Mat3,
    scale: Vec3,
    wx: f32,
    wy: f32,
    wd: f32,
    s0: f32,
    s1: f32,
}

#[cube]
impl ExactSums {
    fn zero() -> ExactSums {
        ExactSums {
            axes: Mat3::zero(),
            scale: Vec3::zero(),
            wx: 0.0f32,
            wy: 0.0f32,
            wd: 0.0f32,
            s0: 0.0f32,
            s1: 0.0f32,
        }
    }
}

/// One pixel's contribution to [`ExactSums`], for the upstream weight `u = Σ_c ρ_c ∂L/∂value_c`.
/// The value depends on `a`, `b`, `Q` and `σ_i` ([`exact_ray`]): `α = u·∂f/∂a =
/// u·base·[T (q − 1)/(2a) + ∂T/∂a]`, `β = u·base·∂T/∂b`, `γ = u·∂f/∂Q = −u·base·T/(2a)`, and
/// `∂Q/∂s_j = −2 Σ_{l≠j} n_l² / s_j` (a sum of squares: no cancellation).
#[cube]
fn exact_pixel(acc: ExactSums, g: RayGaussian, ray: Ray, u: f32, z: f32, sdd: f32) -> ExactSums {
    let inv_sqrt_pi = 0.564_189_6f32;
    let a = ray.a;
    let s = ray.s;
    let ub = u * ray.base;
    let e0 = inv_sqrt_pi * f32::exp(-ray.u0 * ray.u0);
    let e1 = inv_sqrt_pi * f32::exp(-ray.u1 * ray.u1);
    // ∂u_i/∂a = σ_i/s − u_i/(2a), ∂u_i/∂b = 1/s, ∂u_i/∂σ_i = a/s.
    let du0_da = -z / s - ray.u0 / (2.0f32 * a);
    let du1_da = (sdd - z) / s - ray.u1 / (2.0f32 * a);
    let alpha = ub * (ray.t * (ray.qq / a - 1.0f32) / (2.0f32 * a) + e1 * du1_da - e0 * du0_da);
    let beta = ub * (e1 - e0) / s;
    let gamma = -ub * ray.t / (2.0f32 * a);
    let inv_s = Vec3::new(1.0f32 / g.scale.x, 1.0f32 / g.scale.y, 1.0f32 / g.scale.z);
    let inv2 = inv_s.mul(inv_s);
    let kl = g.cofactor_scales();
    let cd = ray
        .ad
        .scale(2.0f32 * alpha)
        .add(ray.aw.scale(beta))
        .mul(inv2);
    let cw = ray.ad.mul(inv2).scale(beta);
    let cc = ray.ac.mul(kl).mul(kl).scale(2.0f32 * gamma);
    let d_axes = Mat3::outer(cd, ray.d)
        .add(Mat3::outer(cw, ray.w))
        .add(Mat3::outer(cc, ray.c));
    let gc = g.axes.t_mul_vec(cc);
    let pd = g.axes.t_mul_vec(ray.ad.mul(inv2));
    // Σ_{l≠j} n_l², n_l = (A_l · c)/(s_m s_n).
    let n = ray.ac.mul(kl);
    let n2 = n.mul(n);
    let rest = Vec3::new(n2.y + n2.z, n2.z + n2.x, n2.x + n2.y);
    let d_scale = ray
        .ad
        .mul(ray.ad)
        .scale(alpha)
        .add(ray.ad.mul(ray.aw).scale(beta))
        .mul(inv2)
        .mul(inv_s)
        .scale(-2.0f32)
        .sub(rest.mul(inv_s).scale(2.0f32 * gamma));
    // ∂w = β Σ⁻¹D + D × ∂c (c = w × D), x and y.
    let gwx = beta * pd.x + ray.d.y * gc.z - gc.y;
    let gwy = beta * pd.y + gc.x - ray.d.x * gc.z;
    ExactSums {
        axes: acc.axes.add(d_axes),
        scale: acc.scale.add(d_scale),
        wx: acc.wx + gwx,
        wy: acc.wy + gwy,
        wd: acc.wd + gwx * ray.d.x + gwy * ray.d.y,
        s0: acc.s0 - ub * e0 * a / s,
        s1: acc.s1 + ub * e1 * a / s,
    }
}

/// Exact-mode backward, one unit per Gaussian: for every view it gathers the footprint's
/// [`ExactSums`], then chains them to the camera-frame centre (and the screen offset) and through
/// `A = (W R)ᵀ` to the rotation.
#[cube(launch)]
pub fn backward_exact_kernel(
    gaussians: &GaussianBuffers,
    screen: &Tensor<f32>,
    cams: &Tensor<f32>,
    prepared: &Tensor<f32>,
    grad: &Tensor<f32>,
    grads: &mut GaussianBuffers,
    g_screen: &mut Tensor<f32>,
    uniforms: &ProjectUniforms,
    #[comptime] m: usize,
) {
    let i = ABSOLUTE_POS;
    let kk = uniforms.k as usize;
    if i >= kk {
        terminate!();
    }
    let rows = uniforms.rows;
    let cols = uniforms.cols;
    let cutoff = uniforms.cutoff;
    let cut2 = cutoff * cutoff;
    let cols_f = f32::cast_from(cols);
    let rows_f = f32::cast_from(rows);
    let plane = (rows * cols) as usize;
    let f = factors(Params::load(gaussians, i));
    // Totals over views: ∂mean, ∂scale, ∂R; ∂density (m).
    let mut t_mean = Vec3::zero();
    let mut t_scale = Vec3::zero();
    let mut t_rot = Mat3::zero();
    let mut total_d = Array::<f32>::new(m);
    let mut sums = Array::<f32>::new(m);
    for c in 0..m {
        total_d[c] = 0.0f32;
    }
    for v in 0..uniforms.n_views as usize {
        let so = 2 * (v * kk + i);
        g_screen[so] = 0.0f32;
        g_screen[so + 1] = 0.0f32;
        let rec = ExactRecord::load(prepared, (v * kk + i) * EXACT_WIDTH);
        let bb = rec.bbox.clip(cols_f, rows_f);
        if f.ok && !bb.is_empty() {
            for c in 0..m {
                sums[c] = 0.0f32;
            }
            let cam = View::load(cams, v);
            let z = rec.g.centre.z;
            let mut acc = ExactSums::zero();
            let mut y = u32::cast_from(bb.y0);
            let y_end = u32::cast_from(bb.y1);
            let x_start = u32::cast_from(bb.x0);
            let x_end = u32::cast_from(bb.x1);
            while y < y_end {
                let mut x = x_start;
                while x < x_end {
                    let ray = exact_ray(rec.g, cam, f32::cast_from(x), f32::cast_from(y), cut2);
                    if ray.ok {
                        let px = (y * cols + x) as usize;
                        let mut u = 0.0f32;
                        for c in 0..m {
                            let g = grad[(v * m + c) * plane + px];
                            sums[c] += g * ray.value;
                            u += gaussians.densities[i * m + c] * g;
                        }
                        acc = exact_pixel(acc, rec.g, ray, u, z, cam.sdd);
                    }
                    x += 1;
                }
                y += 1;
            }
            // Chain to the camera-frame centre: x_c' = x_c + shift(offset), w = z_c L − x_c'
            // (cone; parallel: L − x_c'), σ₀ = −z_c, σ₁ = sdd − z_c.
            let gx = -acc.wx;
            let gy = -acc.wy;
            let mut gz = acc.wd - acc.s0 - acc.s1;
            let mut gsx = gx / cam.fx;
            let mut gsy = gy / cam.fy;
            if cam.cone {
                gz += gx * screen[so] / cam.fx + gy * screen[so + 1] / cam.fy;
                gsx = gx * z / cam.fx;
                gsy = gy * z / cam.fy;
            }
            let d_mean = cam.rot.t_mul_vec(Vec3::new(gx, gy, gz));
            // A = (W R)ᵀ: ∂R = Wᵀ ∂Aᵀ.
            let d_rot = cam.rot.transpose().mul(acc.axes.transpose());
            let mut good = finite(gsx)
                && finite(gsy)
                && d_mean.is_finite()
                && acc.scale.is_finite()
                && d_rot.is_finite();
            for c in 0..m {
                if !finite(sums[c]) {
                    good = false;
                }
            }
            if good {
                t_mean = t_mean.add(d_mean);
                t_scale = t_scale.add(acc.scale);
                t_rot = t_rot.add(d_rot);
                for c in 0..m {
                    total_d[c] += sums[c];
                }
                g_screen[so] = gsx;
                g_screen[so + 1] = gsy;
            }
        }
    }
    let q = quat_backward(f, t_rot);
    let zero = 0.0f32;
    t_mean.store(&mut grads.means, 3 * i);
    t_scale.store(&mut grads.scales, 3 * i);
    grads.rotations[4 * i] = select(f.ok, q.w, zero);
    grads.rotations[4 * i + 1] = select(f.ok, q.x, zero);
    grads.rotations[4 * i + 2] = select(f.ok, q.y, zero);
    grads.rotations[4 * i + 3] = select(f.ok, q.z, zero);
    for c in 0..m {
        grads.densities[i * m + c] = total_d[c];
    }
}
