//! Projection kernels: per-(view, Gaussian) preparation, tile forward, per-Gaussian backward.
//!
//! * [`prepare_kernel`] writes the same `[V, K, PREPARED_WIDTH]` records as the CPU
//!   [`crate::cpu::project_prepare`] (`[mx, my, a, β, γ, μ, x0, x1, y0, y1]`, zeros if culled).
//! * [`forward_kernel`]: one cube per (16×16 tile, view). The cube walks the Gaussians in steps
//!   of 1024 (4 per unit), tests each one's pixel box against the tile, compacts the hits in
//!   index order with a prefix sum in shared memory ([`super::stage_chunk`]) and every pixel sums
//!   the compacted list: binning without a global sort or a host read-back of the pair count, no per-pixel scan of
//!   all Gaussians, and the same summation order as the CPU kernel.
//! * [`backward_kernel`]: one unit per Gaussian gathers its footprint in every view (pixel
//!   moments as in the CPU backward), then chains them to its parameters. Every output is owned
//!   by one unit: no atomics, deterministic.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::{CHUNK, PER_UNIT, STEP, stage_chunk};
use crate::cpu::PREPARED_WIDTH as PW;
use crate::cube::math::{ST_CONIC, ST_LEN, ST_MU, finite, splat_backward, splat_state};

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

#[cube(launch)]
pub fn forward_kernel(
    prepared: &Tensor<f32>,
    densities: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    rows: u32,
    cols: u32,
    cut2: f32,
    #[comptime] m: usize,
) {
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
    let kk = k as usize;
    let base = v * kk;
    let mut start = 0usize;
    while start < kk {
        let first = start + t * PER_UNIT;
        let mut hits = 0u32;
        for i in 0..PER_UNIT {
            let j = first + i;
            if j < kk {
                let o = (base + j) * PW;
                let x0 = prepared[o + 6];
                let x1 = f32::min(prepared[o + 7], cols_f);
                let y0 = prepared[o + 8];
                let y1 = f32::min(prepared[o + 9], rows_f);
                if x0 < x1 && y0 < y1 && x0 < tx1f && x1 > tx0f && y0 < ty1f && y1 > ty0f {
                    hits |= 1u32 << i as u32;
                }
            }
        }
        let n = stage_chunk(hits, first, t, &mut scan, &mut ids);
        for e in 0..n as usize {
            let gi = ids[e] as usize;
            let r = (base + gi) * PW;
            let inside = pxf >= prepared[r + 6]
                && pxf < prepared[r + 7]
                && pyf >= prepared[r + 8]
                && pyf < prepared[r + 9];
            let nhq = neg_half_q(
                prepared[r + 2],
                prepared[r + 3],
                prepared[r + 4],
                pxf - prepared[r],
                pyf - prepared[r + 1],
                cut2,
            );
            if inside && nhq <= 0.0f32 {
                let g = f32::exp(nhq);
                let mu = prepared[r + 5];
                for c in 0..m {
                    acc[c] += densities[gi * m + c] * mu * g;
                }
            }
        }
        sync_cube();
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
