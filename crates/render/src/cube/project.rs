//! Projection kernels: per-(view, Gaussian) preparation, tile forward, per-Gaussian backward.
//!
//! * [`prepare_kernel`] writes one [`AffineRecord`] per view and Gaussian (the CPU
//!   [`crate::cpu::project_prepare`]'s record: `[mx, my, a, β, γ, μ, x0, x1, y0, y1]`, zeros if
//!   culled); the exact mode prepares its own records ([`super::exact`]).
//! * [`forward_kernel`]: one cube per (16×16 tile, view). The cube walks the Gaussians in steps
//!   of 1024 (4 per unit), skips steps whose union box misses the tile, tests each remaining
//!   Gaussian's pixel box against the tile, compacts the hits in index order with a prefix sum
//!   in shared memory ([`super::stage_chunk`]) and every pixel sums the compacted list: binning
//!   without a global sort or a host read-back of the pair count, no per-pixel scan of all
//!   Gaussians, and the same summation order as the CPU kernel.
//! * [`backward_kernel`] (exact mode: [`super::exact::backward_exact_kernel`]): one unit per
//!   Gaussian gathers its footprint in every view (pixel moments as in the CPU backward), then
//!   chains them to its parameters. Every output is owned by one unit: no atomics,
//!   deterministic.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::exact::{EXACT_BOX, EXACT_WIDTH, ExactRecord};
use super::math::{exact_ray, splat, splat_backward};
use super::types::{
    GaussianBuffers, GeomGrad, Params, ProjectUniforms, Rect, Vec3, View, cell_span,
    densities_finite, finite, offset,
};
use super::{CHUNK, PER_UNIT, STEP, stage_chunk};

/// Detector tile edge in pixels (one cube of `TILE²` units per tile).
pub const TILE: u32 = 16;

/// Floats per [`AffineRecord`] (the CPU's prepared record has the same layout).
pub const AFFINE_WIDTH: usize = 10;
/// Where an [`AffineRecord`] keeps its pixel box.
pub const AFFINE_BOX: usize = 6;

/// An affine splat as the pixel loops read it: the projected centre, the factored conic
/// `a (dx + β dy)² + γ dy²`, the integration factor μ, the pixel box.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct AffineRecord {
    pub mx: f32,
    pub my: f32,
    pub a: f32,
    pub beta: f32,
    pub gamma: f32,
    pub mu: f32,
    pub bbox: Rect,
}

#[cube]
impl AffineRecord {
    /// A culled Gaussian: all zeros (an empty box).
    pub fn culled() -> AffineRecord {
        AffineRecord {
            mx: 0.0f32,
            my: 0.0f32,
            a: 0.0f32,
            beta: 0.0f32,
            gamma: 0.0f32,
            mu: 0.0f32,
            bbox: Rect::empty(),
        }
    }

    pub fn load(t: &Tensor<f32>, o: usize) -> AffineRecord {
        AffineRecord {
            mx: t[o],
            my: t[o + 1],
            a: t[o + 2],
            beta: t[o + 3],
            gamma: t[o + 4],
            mu: t[o + 5],
            bbox: Rect::load(t, o + AFFINE_BOX),
        }
    }

    pub fn store(self, t: &mut Tensor<f32>, o: usize) {
        t[o] = self.mx;
        t[o + 1] = self.my;
        t[o + 2] = self.a;
        t[o + 3] = self.beta;
        t[o + 4] = self.gamma;
        t[o + 5] = self.mu;
        self.bbox.store(t, o + AFFINE_BOX);
    }

    /// `−½ q` of pixel `(x, y)`, or `+1` (no contribution) beyond the cut-off `q > cut²` — the
    /// CPU row kernel's test.
    pub fn neg_half_q(self, x: f32, y: f32, cut2: f32) -> f32 {
        let dx = x - self.mx;
        let dy = y - self.my;
        let gdy = self.gamma * dy * dy;
        let d = dx + self.beta * dy;
        let nhq = -0.5f32 * self.a * d * d - 0.5f32 * gdy;
        let mut r = 1.0f32;
        if cut2 - gdy > 0.0f32 && nhq >= -0.5f32 * cut2 {
            r = nhq;
        }
        r
    }
}

/// Affine-mode preparation: one [`AffineRecord`] per (view, Gaussian) into `out`.
#[cube(launch)]
pub fn prepare_kernel(
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
    let v = idx / kk;
    let i = idx % kk;
    let mut rec = AffineRecord::culled();
    if densities_finite(&gaussians.densities, i, m) {
        let (ox, oy) = offset(screen, v, kk, i);
        let p = Params::load(gaussians, i);
        let s = splat(
            p,
            View::load(cams, v),
            ox,
            oy,
            uniforms.cutoff,
            uniforms.near_fraction,
        );
        if s.ok {
            let a = s.conic.x;
            let beta = s.conic.y / a;
            let gamma = s.conic.z - s.conic.y * beta;
            let (x0, x1) = cell_span(s.mx - s.hx, s.mx + s.hx, uniforms.cols);
            let (y0, y1) = cell_span(s.my - s.hy, s.my + s.hy, uniforms.rows);
            let bbox = Rect { x0, x1, y0, y1 };
            let good = finite(a)
                && a > 0.0f32
                && finite(gamma)
                && gamma > 0.0f32
                && finite(beta)
                && !bbox.is_empty();
            if good {
                rec = AffineRecord {
                    mx: s.mx,
                    my: s.my,
                    a,
                    beta,
                    gamma,
                    mu: s.mu,
                    bbox,
                };
            }
        }
    }
    rec.store(out, idx * AFFINE_WIDTH);
}

/// Forward projection, one cube per (tile, view). `exact` selects the record kind
/// ([`AffineRecord`] or [`ExactRecord`], integrated per pixel by [`exact_ray`]); `bounds` are the
/// step boxes of [`super::step_bounds_kernel`] over the same records.
#[cube(launch)]
pub fn forward_kernel(
    prepared: &Tensor<f32>,
    bounds: &Tensor<f32>,
    densities: &Tensor<f32>,
    cams: &Tensor<f32>,
    out: &mut Tensor<f32>,
    uniforms: &ProjectUniforms,
    #[comptime] m: usize,
    #[comptime] exact: bool,
) {
    let rows = uniforms.rows;
    let cols = uniforms.cols;
    let cut2 = uniforms.cut2;
    let width = comptime![if exact { EXACT_WIDTH } else { AFFINE_WIDTH }];
    let bx = comptime![if exact { EXACT_BOX } else { AFFINE_BOX }];
    let v = CUBE_POS_Z as usize;
    let cam = View::load(cams, v);
    let t = (UNIT_POS_Y * TILE + UNIT_POS_X) as usize;
    let tx0 = CUBE_POS_X * TILE;
    let ty0 = CUBE_POS_Y * TILE;
    let px = tx0 + UNIT_POS_X;
    let py = ty0 + UNIT_POS_Y;
    let cols_f = f32::cast_from(cols);
    let rows_f = f32::cast_from(rows);
    let tx0f = f32::cast_from(tx0);
    let ty0f = f32::cast_from(ty0);
    let tile = Rect {
        x0: tx0f,
        x1: f32::min(tx0f + f32::cast_from(TILE), cols_f),
        y0: ty0f,
        y1: f32::min(ty0f + f32::cast_from(TILE), rows_f),
    };
    let pxf = f32::cast_from(px);
    let pyf = f32::cast_from(py);
    let mut scan = Shared::<[u32]>::new_slice(2 * CHUNK);
    let mut ids = Shared::<[u32]>::new_slice(STEP);
    let mut acc = Array::<f32>::new(m);
    for c in 0..m {
        acc[c] = 0.0f32;
    }
    let kk = uniforms.k as usize;
    let base = v * kk;
    let steps = (kk + STEP - 1) / STEP;
    let mut start = 0usize;
    while start < kk {
        // The step's union box (super::step_bounds_kernel): skip the step, uniformly across the
        // cube, if it misses the tile.
        if Rect::load(bounds, (v * steps + start / STEP) * 4).overlaps(tile) {
            let first = start + t * PER_UNIT;
            let mut hits = 0u32;
            for i in 0..PER_UNIT {
                let j = first + i;
                if j < kk {
                    let bb = Rect::load(prepared, (base + j) * width + bx).clip(cols_f, rows_f);
                    if !bb.is_empty() && bb.overlaps(tile) {
                        hits |= 1u32 << i as u32;
                    }
                }
            }
            let n = stage_chunk(hits, first, t, &mut scan, &mut ids);
            for e in 0..n as usize {
                let gi = ids[e] as usize;
                let r = (base + gi) * width;
                // The pixel's value is Σ_c ρ_c · scale · g: affine scale = μ, g = e^{−q/2} (the
                // CPU's order of operations); exact scale = 1, g = the segment integral.
                // Only pixels inside the box evaluate: a warp (a SIMD group on lavapipe) whose
                // pixels all miss skips the work.
                if Rect::load(prepared, r + bx).contains(pxf, pyf) {
                    let mut hit = false;
                    let mut scale = 1.0f32;
                    let mut g = 0.0f32;
                    if exact {
                        let ray = exact_ray(ExactRecord::load(prepared, r).g, cam, pxf, pyf, cut2);
                        if ray.ok {
                            hit = true;
                            g = ray.value;
                        }
                    } else {
                        let rec = AffineRecord::load(prepared, r);
                        let nhq = rec.neg_half_q(pxf, pyf, cut2);
                        if nhq <= 0.0f32 {
                            hit = true;
                            scale = rec.mu;
                            g = f32::exp(nhq);
                        }
                    }
                    if hit {
                        for c in 0..m {
                            acc[c] += densities[gi * m + c] * scale * g;
                        }
                    }
                }
            }
            sync_cube();
        }
        start += STEP;
    }
    if px < cols && py < rows {
        let plane = (rows * cols) as usize;
        let p = (py * cols + px) as usize;
        for c in 0..m {
            out[(v * m + c) * plane + p] = acc[c];
        }
    }
}

/// Affine-mode backward, one unit per Gaussian: gathers the pixel moments of its footprint in
/// every view from `grad` (`[V, M, rows, cols]`), chains them to the Gaussian's parameters
/// (`grads`) and screen offsets (`g_screen`, `[V, K, 2]`).
#[cube(launch)]
pub fn backward_kernel(
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
    let p = Params::load(gaussians, i);
    let mut total = GeomGrad::zero();
    let mut total_d = Array::<f32>::new(m);
    let mut sums = Array::<f32>::new(m);
    for c in 0..m {
        total_d[c] = 0.0f32;
    }
    for v in 0..uniforms.n_views as usize {
        let so = 2 * (v * kk + i);
        g_screen[so] = 0.0f32;
        g_screen[so + 1] = 0.0f32;
        let rec = AffineRecord::load(prepared, (v * kk + i) * AFFINE_WIDTH);
        let bb = rec.bbox.clip(cols_f, rows_f);
        if !bb.is_empty() {
            for c in 0..m {
                sums[c] = 0.0f32;
            }
            // Σ w (dx, dy) and Σ w (dx², dx dy, dy²) with w = G · Σ_c ρ_c ∂L/∂value_c.
            let mut wx = 0.0f32;
            let mut wy = 0.0f32;
            let mut wxx = 0.0f32;
            let mut wxy = 0.0f32;
            let mut wyy = 0.0f32;
            let mut y = u32::cast_from(bb.y0);
            let y_end = u32::cast_from(bb.y1);
            let x_start = u32::cast_from(bb.x0);
            let x_end = u32::cast_from(bb.x1);
            while y < y_end {
                let yf = f32::cast_from(y);
                let dy = yf - rec.my;
                let mut x = x_start;
                while x < x_end {
                    let xf = f32::cast_from(x);
                    let dx = xf - rec.mx;
                    let nhq = rec.neg_half_q(xf, yf, cut2);
                    if nhq <= 0.0f32 {
                        let g = f32::exp(nhq);
                        let px = (y * cols + x) as usize;
                        let mut u = 0.0f32;
                        for c in 0..m {
                            let gc = grad[(v * m + c) * plane + px];
                            sums[c] += gc * g;
                            u += gaussians.densities[i * m + c] * gc;
                        }
                        let w = u * g;
                        wx += w * dx;
                        wy += w * dy;
                        wxx += w * dx * dx;
                        wxy += w * dx * dy;
                        wyy += w * dy * dy;
                    }
                    x += 1;
                }
                y += 1;
            }
            let cam = View::load(cams, v);
            let (ox, oy) = offset(screen, v, kk, i);
            let s = splat(p, cam, ox, oy, cutoff, uniforms.near_fraction);
            if s.ok {
                let mu = s.mu;
                let gmx = mu * (s.conic.x * wx + s.conic.y * wy);
                let gmy = mu * (s.conic.y * wx + s.conic.z * wy);
                let g_conic = Vec3::new(-0.5f32 * mu * wxx, -0.5f32 * mu * wxy, -0.5f32 * mu * wyy);
                let mut g_mu = 0.0f32;
                for c in 0..m {
                    g_mu += gaussians.densities[i * m + c] * sums[c];
                }
                let geo = splat_backward(s, cam, gmx, gmy, g_conic, g_mu);
                let mut good = finite(gmx) && finite(gmy) && geo.is_finite();
                for c in 0..m {
                    if !finite(mu * sums[c]) {
                        good = false;
                    }
                }
                if good {
                    total = total.add(geo);
                    for c in 0..m {
                        total_d[c] += mu * sums[c];
                    }
                    g_screen[so] = gmx;
                    g_screen[so + 1] = gmy;
                }
            }
        }
    }
    total.store(grads, i);
    for c in 0..m {
        grads.densities[i * m + c] = total_d[c];
    }
}
