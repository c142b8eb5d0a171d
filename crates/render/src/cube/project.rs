//! Projection kernels: per-(view, Gaussian) preparation, tile forward, per-Gaussian backward.
//!
//! * [`prepare_kernel`] writes the same `[V, K, PREPARED_WIDTH]` records as the CPU
//!   [`crate::cpu::project_prepare`] (`[mx, my, a, β, γ, μ, x0, x1, y0, y1]`, zeros if culled);
//!   [`prepare_exact_kernel`] writes the exact mode's `[V, K, EX_WIDTH]` records.
//! * [`forward_kernel`]: one cube per (16×16 tile, view). The cube walks the Gaussians in steps
//!   of 1024 (4 per unit), skips steps whose union box misses the tile, tests each remaining
//!   Gaussian's pixel box against the tile, compacts the hits in index order with a prefix sum
//!   in shared memory ([`super::stage_chunk`]) and every pixel sums the compacted list: binning
//!   without a global sort or a host read-back of the pair count, no per-pixel scan of all
//!   Gaussians, and the same summation order as the CPU kernel.
//! * [`backward_kernel`] / [`backward_exact_kernel`]: one unit per Gaussian gathers its
//!   footprint in every view (pixel moments as in the CPU backward), then chains them to its
//!   parameters. Every output is owned by one unit: no atomics, deterministic.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::{CHUNK, PER_UNIT, STEP, stage_chunk};
use crate::cpu::PREPARED_WIDTH as PW;
use crate::cube::math::{
    CAM_CONE, CAM_CX, CAM_CY, CAM_FX, CAM_FY, CAM_SDD, CAM_WIDTH, EX_AXES, EX_BOX, EX_SCALE,
    EX_WIDTH, RAY_A, RAY_AC, RAY_AD, RAY_AW, RAY_BASE, RAY_C, RAY_D, RAY_LEN, RAY_Q, RAY_S, RAY_T,
    RAY_U0, RAY_U1, RAY_VALUE, RAY_W, ST_CONIC, ST_LEN, ST_MU, ST_ROT, ST_S2, ST_SCALE, cell_span,
    exact_ray, factors, finite, quat_backward, splat_backward, splat_state,
};

/// Detector tile edge in pixels (one cube of `TILE²` units per tile).
pub const TILE: u32 = 16;

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn prepare_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    screen: &Tensor<f32>,
    cams: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    n_views: u32,
    rows: u32,
    cols: u32,
    cutoff: f32,
    near_fraction: f32,
    #[comptime] m: usize,
) {
    let idx = ABSOLUTE_POS;
    let kk = k as usize;
    if idx >= kk * n_views as usize {
        terminate!();
    }
    let v = idx / kk;
    let i = idx % kk;
    let o = idx * PW;
    for f in 0..PW {
        out[o + f] = 0.0f32;
    }
    let mut ok = true;
    for c in 0..m {
        if !finite(densities[i * m + c]) {
            ok = false;
        }
    }
    let mut st = Array::<f32>::new(ST_LEN);
    if ok {
        ok = splat_state(
            means,
            scales,
            rotations,
            screen,
            cams,
            i,
            v,
            kk,
            cutoff,
            near_fraction,
            &mut st,
        );
    }
    if ok {
        let a = st[ST_CONIC];
        let beta = st[ST_CONIC + 1] / a;
        let gamma = st[ST_CONIC + 2] - st[ST_CONIC + 1] * beta;
        let mut span = Array::<f32>::new(4usize);
        let (mx, my) = (
            st[crate::cube::math::ST_MEAN],
            st[crate::cube::math::ST_MEAN + 1],
        );
        let (hx, hy) = (
            st[crate::cube::math::ST_HALF],
            st[crate::cube::math::ST_HALF + 1],
        );
        crate::cube::math::cell_span(mx - hx, mx + hx, cols, &mut span, 0);
        crate::cube::math::cell_span(my - hy, my + hy, rows, &mut span, 2);
        let good = finite(a)
            && a > 0.0f32
            && finite(gamma)
            && gamma > 0.0f32
            && finite(beta)
            && span[0] < span[1]
            && span[2] < span[3];
        if good {
            out[o] = mx;
            out[o + 1] = my;
            out[o + 2] = a;
            out[o + 3] = beta;
            out[o + 4] = gamma;
            out[o + 5] = st[ST_MU];
            out[o + 6] = span[0];
            out[o + 7] = span[1];
            out[o + 8] = span[2];
            out[o + 9] = span[3];
        }
    }
}

/// `−½ q` of a pixel offset `(dx, dy)` from a splat's factored conic `(a, β, γ)`, or `+1` (no
/// contribution) beyond the cut-off `q > cut²` — the CPU row kernel's test.
#[cube]
fn neg_half_q(a: f32, beta: f32, gamma: f32, dx: f32, dy: f32, cut2: f32) -> f32 {
    let gdy = gamma * dy * dy;
    let d = dx + beta * dy;
    let nhq = -0.5f32 * a * d * d - 0.5f32 * gdy;
    let mut r = 1.0f32;
    if cut2 - gdy > 0.0f32 && nhq >= -0.5f32 * cut2 {
        r = nhq;
    }
    r
}

/// Forward projection, one cube per (tile, view). `exact` selects the record kind: affine
/// records of [`PW`] floats (box at 6) or exact records of [`EX_WIDTH`] floats (box at
/// [`EX_BOX`], integrated per pixel by [`exact_ray`]); `bounds` are the step boxes of
/// [`super::step_bounds_kernel`] over the same records.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn forward_kernel(
    prepared: &Tensor<f32>,
    bounds: &Tensor<f32>,
    densities: &Tensor<f32>,
    cams: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    rows: u32,
    cols: u32,
    cut2: f32,
    #[comptime] m: usize,
    #[comptime] exact: bool,
) {
    let width = comptime![if exact { EX_WIDTH } else { PW }];
    let bx = comptime![if exact { EX_BOX } else { 6usize }];
    let v = CUBE_POS_Z as usize;
    let t = (UNIT_POS_Y * TILE + UNIT_POS_X) as usize;
    let tx0 = CUBE_POS_X * TILE;
    let ty0 = CUBE_POS_Y * TILE;
    let px = tx0 + UNIT_POS_X;
    let py = ty0 + UNIT_POS_Y;
    let cols_f = f32::cast_from(cols);
    let rows_f = f32::cast_from(rows);
    let tx0f = f32::cast_from(tx0);
    let ty0f = f32::cast_from(ty0);
    let tx1f = f32::min(tx0f + f32::cast_from(TILE), cols_f);
    let ty1f = f32::min(ty0f + f32::cast_from(TILE), rows_f);
    let pxf = f32::cast_from(px);
    let pyf = f32::cast_from(py);
    let mut scan = Shared::<[u32]>::new_slice(2 * CHUNK);
    let mut ids = Shared::<[u32]>::new_slice(STEP);
    let mut acc = Array::<f32>::new(m);
    for c in 0..m {
        acc[c] = 0.0f32;
    }
    // The exact mode's ray state (a one-element stub in the affine variant, which never uses it).
    let ray_len = comptime![if exact { RAY_LEN } else { 1usize }];
    let mut ray = Array::<f32>::new(ray_len);
    let kk = k as usize;
    let base = v * kk;
    let steps = (kk + STEP - 1) / STEP;
    let mut start = 0usize;
    while start < kk {
        // The step's union box (super::step_bounds_kernel): skip the step, uniformly across the
        // cube, if it misses the tile.
        let b = (v * steps + start / STEP) * 4;
        if bounds[b] < tx1f && bounds[b + 1] > tx0f && bounds[b + 2] < ty1f && bounds[b + 3] > ty0f
        {
            let first = start + t * PER_UNIT;
            let mut hits = 0u32;
            for i in 0..PER_UNIT {
                let j = first + i;
                if j < kk {
                    let o = (base + j) * width + bx;
                    let x0 = prepared[o];
                    let x1 = f32::min(prepared[o + 1], cols_f);
                    let y0 = prepared[o + 2];
                    let y1 = f32::min(prepared[o + 3], rows_f);
                    if x0 < x1 && y0 < y1 && x0 < tx1f && x1 > tx0f && y0 < ty1f && y1 > ty0f {
                        hits |= 1u32 << i as u32;
                    }
                }
            }
            let n = stage_chunk(hits, first, t, &mut scan, &mut ids);
            for e in 0..n as usize {
                let gi = ids[e] as usize;
                let r = (base + gi) * width;
                let inside = pxf >= prepared[r + bx]
                    && pxf < prepared[r + bx + 1]
                    && pyf >= prepared[r + bx + 2]
                    && pyf < prepared[r + bx + 3];
                // The pixel's value is Σ_c ρ_c · scale · g: affine scale = μ, g = e^{−q/2} (the
                // CPU's order of operations); exact scale = 1, g = the segment integral.
                // Only pixels inside the box evaluate: a warp (a SIMD group on lavapipe) whose
                // pixels all miss skips the work.
                if inside {
                    let mut hit = false;
                    let mut scale = 1.0f32;
                    let mut g = 0.0f32;
                    if exact {
                        if exact_ray(prepared, r, cams, v, pxf, pyf, cut2, &mut ray) {
                            hit = true;
                            g = ray[RAY_VALUE];
                        }
                    } else {
                        let nhq = neg_half_q(
                            prepared[r + 2],
                            prepared[r + 3],
                            prepared[r + 4],
                            pxf - prepared[r],
                            pyf - prepared[r + 1],
                            cut2,
                        );
                        if nhq <= 0.0f32 {
                            hit = true;
                            scale = prepared[r + 5];
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

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn backward_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    screen: &Tensor<f32>,
    cams: &Tensor<f32>,
    prepared: &Tensor<f32>,
    grad: &Tensor<f32>,
    g_means: &mut Tensor<f32>,
    g_scales: &mut Tensor<f32>,
    g_rotations: &mut Tensor<f32>,
    g_densities: &mut Tensor<f32>,
    g_screen: &mut Tensor<f32>,
    k: u32,
    n_views: u32,
    rows: u32,
    cols: u32,
    cutoff: f32,
    near_fraction: f32,
    #[comptime] m: usize,
) {
    let i = ABSOLUTE_POS;
    let kk = k as usize;
    if i >= kk {
        terminate!();
    }
    let cut2 = cutoff * cutoff;
    let cols_f = f32::cast_from(cols);
    let rows_f = f32::cast_from(rows);
    let plane = (rows * cols) as usize;
    let mut total = Array::<f32>::new(10usize);
    for e in 0..10usize {
        total[e] = 0.0f32;
    }
    let mut total_d = Array::<f32>::new(m);
    let mut sums = Array::<f32>::new(m);
    for c in 0..m {
        total_d[c] = 0.0f32;
    }
    let mut st = Array::<f32>::new(ST_LEN);
    let mut tmp = Array::<f32>::new(32usize);
    let mut geo = Array::<f32>::new(10usize);
    let mut g_mean = Array::<f32>::new(2usize);
    let mut g_conic = Array::<f32>::new(3usize);
    for v in 0..n_views as usize {
        let o = (v * kk + i) * PW;
        g_screen[2 * (v * kk + i)] = 0.0f32;
        g_screen[2 * (v * kk + i) + 1] = 0.0f32;
        let mx = prepared[o];
        let my = prepared[o + 1];
        let a = prepared[o + 2];
        let beta = prepared[o + 3];
        let gamma = prepared[o + 4];
        let x0 = prepared[o + 6];
        let x1 = f32::min(prepared[o + 7], cols_f);
        let y0 = prepared[o + 8];
        let y1 = f32::min(prepared[o + 9], rows_f);
        if x0 < x1 && y0 < y1 {
            for c in 0..m {
                sums[c] = 0.0f32;
            }
            let mut wx = 0.0f32;
            let mut wy = 0.0f32;
            let mut wxx = 0.0f32;
            let mut wxy = 0.0f32;
            let mut wyy = 0.0f32;
            let mut y = u32::cast_from(y0);
            let y_end = u32::cast_from(y1);
            let x_start = u32::cast_from(x0);
            let x_end = u32::cast_from(x1);
            while y < y_end {
                let dy = f32::cast_from(y) - my;
                let mut x = x_start;
                while x < x_end {
                    let dx = f32::cast_from(x) - mx;
                    let nhq = neg_half_q(a, beta, gamma, dx, dy, cut2);
                    if nhq <= 0.0f32 {
                        let g = f32::exp(nhq);
                        let p = (y * cols + x) as usize;
                        let mut u = 0.0f32;
                        for c in 0..m {
                            let gc = grad[(v * m + c) * plane + p];
                            sums[c] += gc * g;
                            u += densities[i * m + c] * gc;
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
            let ok = splat_state(
                means,
                scales,
                rotations,
                screen,
                cams,
                i,
                v,
                kk,
                cutoff,
                near_fraction,
                &mut st,
            );
            if ok {
                let mu = st[ST_MU];
                let ca = st[ST_CONIC];
                let cb = st[ST_CONIC + 1];
                let cc = st[ST_CONIC + 2];
                g_mean[0] = mu * (ca * wx + cb * wy);
                g_mean[1] = mu * (cb * wx + cc * wy);
                g_conic[0] = -0.5f32 * mu * wxx;
                g_conic[1] = -0.5f32 * mu * wxy;
                g_conic[2] = -0.5f32 * mu * wyy;
                let mut g_mu = 0.0f32;
                for c in 0..m {
                    g_mu += densities[i * m + c] * sums[c];
                }
                splat_backward(&st, cams, v, &g_mean, &g_conic, g_mu, &mut tmp, &mut geo);
                let mut good = finite(g_mean[0]) && finite(g_mean[1]);
                for e in 0..10usize {
                    if !finite(geo[e]) {
                        good = false;
                    }
                }
                for c in 0..m {
                    if !finite(mu * sums[c]) {
                        good = false;
                    }
                }
                if good {
                    for e in 0..10usize {
                        total[e] += geo[e];
                    }
                    for c in 0..m {
                        total_d[c] += mu * sums[c];
                    }
                    g_screen[2 * (v * kk + i)] = g_mean[0];
                    g_screen[2 * (v * kk + i) + 1] = g_mean[1];
                }
            }
        }
    }
    for a in 0..3usize {
        g_means[3 * i + a] = total[a];
        g_scales[3 * i + a] = total[3 + a];
    }
    for a in 0..4usize {
        g_rotations[4 * i + a] = total[6 + a];
    }
    for c in 0..m {
        g_densities[i * m + c] = total_d[c];
    }
}

/// Exact-mode preparation: per (view, Gaussian), the record of [`EX_WIDTH`] floats (the
/// camera-frame centre with the screen offset applied, the camera-frame axes and scales, the
/// pixel box), as the CPU's `exact_splat`: the cut-off box `centre ± cutoff·√diag Σ_c` must
/// overlap `0 ≤ z ≤ sdd`; its projected corners bound the pixel box (cone: the whole detector
/// if the box reaches the source plane). Zeros if culled.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn prepare_exact_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    screen: &Tensor<f32>,
    cams: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    n_views: u32,
    rows: u32,
    cols: u32,
    cutoff: f32,
    #[comptime] m: usize,
) {
    let idx = ABSOLUTE_POS;
    let kk = k as usize;
    if idx >= kk * n_views as usize {
        terminate!();
    }
    let v = idx / kk;
    let i = idx % kk;
    let o = idx * EX_WIDTH;
    for f in 0..EX_WIDTH {
        out[o + f] = 0.0f32;
    }
    let mut ok = true;
    for c in 0..m {
        if !finite(densities[i * m + c]) {
            ok = false;
        }
    }
    let mut st = Array::<f32>::new(ST_LEN);
    if ok {
        ok = factors(means, scales, rotations, i, &mut st);
    }
    if ok {
        let cb = v * CAM_WIDTH;
        let fx = cams[cb + CAM_FX];
        let fy = cams[cb + CAM_FY];
        let cx = cams[cb + CAM_CX];
        let cy = cams[cb + CAM_CY];
        let sdd = cams[cb + CAM_SDD];
        let cone = cams[cb + CAM_CONE] > 0.5f32;
        let mut t = Array::<f32>::new(3usize);
        for r in 0..3usize {
            t[r] = cams[cb + 3 * r] * means[3 * i]
                + cams[cb + 3 * r + 1] * means[3 * i + 1]
                + cams[cb + 3 * r + 2] * means[3 * i + 2]
                + cams[cb + 9 + r];
        }
        let z = t[2];
        let so = 2 * idx;
        let mut x = t[0] + screen[so] / fx;
        let mut y = t[1] + screen[so + 1] / fy;
        if cone {
            x = t[0] + screen[so] * z / fx;
            y = t[1] + screen[so + 1] * z / fy;
        }
        // A_j = (W R)_j; the camera-frame covariance diagonal Σ_j A_rj² s_j².
        let mut axes = Array::<f32>::new(9usize);
        let mut h = Array::<f32>::new(3usize);
        for r in 0..3usize {
            h[r] = 0.0f32;
        }
        let mut good = true;
        for j in 0..3usize {
            for r in 0..3usize {
                let a = cams[cb + 3 * r] * st[ST_ROT + j]
                    + cams[cb + 3 * r + 1] * st[ST_ROT + 3 + j]
                    + cams[cb + 3 * r + 2] * st[ST_ROT + 6 + j];
                axes[3 * j + r] = a;
                h[r] += a * a * st[ST_S2 + j];
            }
        }
        for r in 0..3usize {
            h[r] = cutoff * f32::sqrt(h[r]);
            if !finite(h[r]) {
                good = false;
            }
        }
        if !(finite(x) && finite(y) && finite(z)) {
            good = false;
        }
        let z_lo = z - h[2];
        let z_hi = z + h[2];
        if z_hi < 0.0f32 || z_lo > sdd {
            good = false;
        }
        let mut bb = Array::<f32>::new(4usize);
        bb[0] = fx * (x - h[0]) + cx;
        bb[1] = fx * (x + h[0]) + cx;
        bb[2] = fy * (y - h[1]) + cy;
        bb[3] = fy * (y + h[1]) + cy;
        if cone {
            let z_min = f32::max(sdd * 1.0e-9f32, 1.0e-30f32);
            // ±3e38 stands for ±∞ (no infinity literal in WGSL): the whole detector.
            if z_lo <= z_min {
                bb[0] = -3.0e38f32;
                bb[1] = 3.0e38f32;
                bb[2] = -3.0e38f32;
                bb[3] = 3.0e38f32;
            } else {
                bb[0] = 3.0e38f32;
                bb[1] = -3.0e38f32;
                bb[2] = 3.0e38f32;
                bb[3] = -3.0e38f32;
                for corner in 0..8u32 {
                    let sx = select((corner & 1u32) == 0u32, -1.0f32, 1.0f32);
                    let sy = select((corner & 2u32) == 0u32, -1.0f32, 1.0f32);
                    let zz = select((corner & 4u32) == 0u32, z_lo, z_hi);
                    let u = fx * (x + sx * h[0]) / zz + cx;
                    let w = fy * (y + sy * h[1]) / zz + cy;
                    bb[0] = f32::min(bb[0], u);
                    bb[1] = f32::max(bb[1], u);
                    bb[2] = f32::min(bb[2], w);
                    bb[3] = f32::max(bb[3], w);
                }
            }
        }
        let mut span = Array::<f32>::new(4usize);
        cell_span(bb[0], bb[1], cols, &mut span, 0);
        cell_span(bb[2], bb[3], rows, &mut span, 2);
        if !(span[0] < span[1] && span[2] < span[3]) {
            good = false;
        }
        if good {
            out[o] = x;
            out[o + 1] = y;
            out[o + 2] = z;
            for f in 0..9usize {
                out[o + EX_AXES + f] = axes[f];
            }
            for j in 0..3usize {
                out[o + EX_SCALE + j] = st[ST_SCALE + j];
            }
            for f in 0..4usize {
                out[o + EX_BOX + f] = span[f];
            }
        }
    }
}

/// Exact-mode backward, one unit per Gaussian: for every view it gathers the footprint's
/// derivatives with respect to the record's quantities (the axes `A_j`, the scales, the offset
/// `w`, the segment ends `σ₀ = −z_c`, `σ₁ = sdd − z_c`), then chains them to the camera-frame
/// centre (and the screen offset) and through `A = W R` to the rotation. The value depends on
/// `a`, `b`, `Q` and `σ_i` ([`exact_ray`]); per pixel, with `u = Σ_c ρ_c ∂L/∂value_c`:
/// `α = u·∂f/∂a = u·base·[T (q − 1)/(2a) + ∂T/∂a]`, `β = u·base·∂T/∂b`, `γ = u·∂f/∂Q =
/// −u·base·T/(2a)`, and `∂Q/∂s_j = −2 Σ_{l≠j} n_l² / s_j` (a sum of squares: no cancellation).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn backward_exact_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    screen: &Tensor<f32>,
    cams: &Tensor<f32>,
    prepared: &Tensor<f32>,
    grad: &Tensor<f32>,
    g_means: &mut Tensor<f32>,
    g_scales: &mut Tensor<f32>,
    g_rotations: &mut Tensor<f32>,
    g_densities: &mut Tensor<f32>,
    g_screen: &mut Tensor<f32>,
    k: u32,
    n_views: u32,
    rows: u32,
    cols: u32,
    cutoff: f32,
    #[comptime] m: usize,
) {
    let i = ABSOLUTE_POS;
    let kk = k as usize;
    if i >= kk {
        terminate!();
    }
    let cut2 = cutoff * cutoff;
    let cols_f = f32::cast_from(cols);
    let rows_f = f32::cast_from(rows);
    let plane = (rows * cols) as usize;
    let inv_sqrt_pi = 0.564_189_6f32;
    let mut st = Array::<f32>::new(ST_LEN);
    let ok = factors(means, scales, rotations, i, &mut st);
    // Totals over views: ∂mean (3), ∂scale (3), ∂R (9, row-major); ∂density (m).
    let mut total = Array::<f32>::new(15usize);
    for e in 0..15usize {
        total[e] = 0.0f32;
    }
    let mut total_d = Array::<f32>::new(m);
    let mut sums = Array::<f32>::new(m);
    for c in 0..m {
        total_d[c] = 0.0f32;
    }
    let mut ray = Array::<f32>::new(RAY_LEN);
    // Per view: ∂A (9, row j), ∂s (3), ∂w (2), Σ ∂w·D_xy (1), ∂σ₀, ∂σ₁ (2).
    let mut acc = Array::<f32>::new(17usize);
    let mut view = Array::<f32>::new(15usize);
    let mut gc = Array::<f32>::new(3usize);
    let mut pd = Array::<f32>::new(3usize);
    for v in 0..n_views as usize {
        let o = (v * kk + i) * EX_WIDTH;
        g_screen[2 * (v * kk + i)] = 0.0f32;
        g_screen[2 * (v * kk + i) + 1] = 0.0f32;
        let x0 = prepared[o + EX_BOX];
        let x1 = f32::min(prepared[o + EX_BOX + 1], cols_f);
        let y0 = prepared[o + EX_BOX + 2];
        let y1 = f32::min(prepared[o + EX_BOX + 3], rows_f);
        if ok && x0 < x1 && y0 < y1 {
            for c in 0..m {
                sums[c] = 0.0f32;
            }
            for e in 0..17usize {
                acc[e] = 0.0f32;
            }
            let z = prepared[o + 2];
            let sdd = cams[v * CAM_WIDTH + CAM_SDD];
            let mut y = u32::cast_from(y0);
            let y_end = u32::cast_from(y1);
            let x_start = u32::cast_from(x0);
            let x_end = u32::cast_from(x1);
            while y < y_end {
                let mut x = x_start;
                while x < x_end {
                    let hit = exact_ray(
                        prepared,
                        o,
                        cams,
                        v,
                        f32::cast_from(x),
                        f32::cast_from(y),
                        cut2,
                        &mut ray,
                    );
                    if hit {
                        let p = (y * cols + x) as usize;
                        let mut u = 0.0f32;
                        for c in 0..m {
                            let g = grad[(v * m + c) * plane + p];
                            sums[c] += g * ray[RAY_VALUE];
                            u += densities[i * m + c] * g;
                        }
                        let a = ray[RAY_A];
                        let s = ray[RAY_S];
                        let u0 = ray[RAY_U0];
                        let u1 = ray[RAY_U1];
                        let tf = ray[RAY_T];
                        let qq = ray[RAY_Q];
                        let ub = u * ray[RAY_BASE];
                        let e0 = inv_sqrt_pi * f32::exp(-u0 * u0);
                        let e1 = inv_sqrt_pi * f32::exp(-u1 * u1);
                        // ∂u_i/∂a = σ_i/s − u_i/(2a), ∂u_i/∂b = 1/s, ∂u_i/∂σ_i = a/s.
                        let du0_da = -z / s - u0 / (2.0f32 * a);
                        let du1_da = (sdd - z) / s - u1 / (2.0f32 * a);
                        let alpha = ub
                            * (tf * (qq / a - 1.0f32) / (2.0f32 * a) + e1 * du1_da - e0 * du0_da);
                        let beta = ub * (e1 - e0) / s;
                        let gamma = -ub * tf / (2.0f32 * a);
                        for e in 0..3usize {
                            gc[e] = 0.0f32;
                            pd[e] = 0.0f32;
                        }
                        for j in 0..3usize {
                            let sj = prepared[o + EX_SCALE + j];
                            let inv2 = 1.0f32 / (sj * sj);
                            let kl = 1.0f32
                                / (prepared[o + EX_SCALE + (j + 1) % 3]
                                    * prepared[o + EX_SCALE + (j + 2) % 3]);
                            let ad = ray[RAY_AD + j];
                            let aw = ray[RAY_AW + j];
                            let ac = ray[RAY_AC + j];
                            let cd = (2.0f32 * alpha * ad + beta * aw) * inv2;
                            let cw = beta * ad * inv2;
                            let cc = 2.0f32 * gamma * ac * kl * kl;
                            for e in 0..3usize {
                                acc[3 * j + e] +=
                                    cd * ray[RAY_D + e] + cw * ray[RAY_W + e] + cc * ray[RAY_C + e];
                                let axis = prepared[o + EX_AXES + 3 * j + e];
                                gc[e] += cc * axis;
                                pd[e] += ad * inv2 * axis;
                            }
                            // Σ_{l≠j} n_l², n_l = (A_l · c)/(s_m s_n).
                            let mut rest = 0.0f32;
                            for l in 0..3usize {
                                if l != j {
                                    let n = ray[RAY_AC + l]
                                        / (prepared[o + EX_SCALE + (l + 1) % 3]
                                            * prepared[o + EX_SCALE + (l + 2) % 3]);
                                    rest += n * n;
                                }
                            }
                            acc[9 + j] += -2.0f32 * (alpha * ad * ad + beta * ad * aw) * inv2 / sj
                                - 2.0f32 * gamma * rest / sj;
                        }
                        // ∂w = β Σ⁻¹D + D × ∂c (c = w × D), x and y.
                        let gwx = beta * pd[0] + ray[RAY_D + 1] * gc[2] - gc[1];
                        let gwy = beta * pd[1] + gc[0] - ray[RAY_D] * gc[2];
                        acc[12] += gwx;
                        acc[13] += gwy;
                        acc[14] += gwx * ray[RAY_D] + gwy * ray[RAY_D + 1];
                        acc[15] += -ub * e0 * a / s;
                        acc[16] += ub * e1 * a / s;
                    }
                    x += 1;
                }
                y += 1;
            }
            // Chain to the camera-frame centre: x_c' = x_c + shift(offset), w = z_c L − x_c'
            // (cone; parallel: L − x_c'), σ₀ = −z_c, σ₁ = sdd − z_c.
            let cb = v * CAM_WIDTH;
            let fx = cams[cb + CAM_FX];
            let fy = cams[cb + CAM_FY];
            let gx = -acc[12];
            let gy = -acc[13];
            let mut gz = acc[14] - acc[15] - acc[16];
            let so = 2 * (v * kk + i);
            let mut gsx = gx / fx;
            let mut gsy = gy / fy;
            if cams[cb + CAM_CONE] > 0.5f32 {
                gz += gx * screen[so] / fx + gy * screen[so + 1] / fy;
                gsx = gx * z / fx;
                gsy = gy * z / fy;
            }
            for a in 0..3usize {
                view[a] = cams[cb + a] * gx + cams[cb + 3 + a] * gy + cams[cb + 6 + a] * gz;
            }
            // A = W R: ∂R[:, j] = Wᵀ ∂A_j.
            for j in 0..3usize {
                view[3 + j] = acc[9 + j];
                for c in 0..3usize {
                    view[6 + 3 * c + j] = cams[cb + c] * acc[3 * j]
                        + cams[cb + 3 + c] * acc[3 * j + 1]
                        + cams[cb + 6 + c] * acc[3 * j + 2];
                }
            }
            let mut good = finite(gsx) && finite(gsy);
            for e in 0..15usize {
                if !finite(view[e]) {
                    good = false;
                }
            }
            for c in 0..m {
                if !finite(sums[c]) {
                    good = false;
                }
            }
            if good {
                for e in 0..15usize {
                    total[e] += view[e];
                }
                for c in 0..m {
                    total_d[c] += sums[c];
                }
                g_screen[so] = gsx;
                g_screen[so + 1] = gsy;
            }
        }
    }
    let mut g_rot = Array::<f32>::new(9usize);
    for e in 0..9usize {
        g_rot[e] = total[6 + e];
    }
    let mut g_quat = Array::<f32>::new(4usize);
    quat_backward(&st, &g_rot, &mut g_quat);
    for a in 0..3usize {
        g_means[3 * i + a] = total[a];
        g_scales[3 * i + a] = total[3 + a];
    }
    for a in 0..4usize {
        g_rotations[4 * i + a] = select(ok, g_quat[a], 0.0f32);
    }
    for c in 0..m {
        g_densities[i * m + c] = total_d[c];
    }
}
