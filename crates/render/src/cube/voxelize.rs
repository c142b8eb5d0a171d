//! Voxelization kernels, organised like the projection ones ([`super::project`]):
//! per-Gaussian preparation ([`prepare_kernel`], records of [`VOX_WIDTH`] floats), a brick
//! forward that culls and compacts Gaussians per 8×8×4 brick ([`forward_kernel`]) and a
//! per-Gaussian gather backward ([`backward_kernel`]).
//!
//! The grid is passed as `[nx, ny, nz, dx, dy, dz, ox, oy, oz]` (f32): voxel `(ix, iy, iz)` has
//! its centre at `o + (i + ½ − n/2)·d` per axis, as [`crate::VoxelGrid`].

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::math::{ST_LEN, ST_ROT, ST_SCALE, factors, finite, quat_backward, variance};
use super::{CHUNK, PER_UNIT, STEP, stage_chunk};

/// Width of one Gaussian's voxel record: `[mean (3), scaled axes w_j = r_j / s_j (3 × 3),
/// lo (3), hi (3), 0, 0]` (zeros if culled).
pub const VOX_WIDTH: usize = 20;
/// Brick edge (units per cube: `BX · BY · BZ` = [`CHUNK`]).
pub const BX: u32 = 8;
pub const BY: u32 = 8;
pub const BZ: u32 = 4;

/// Centre of voxel `i` along `axis` of `grid`.
#[cube]
fn centre(grid: &Tensor<f32>, axis: usize, i: u32) -> f32 {
    grid[6 + axis] + (f32::cast_from(i) + 0.5f32 - grid[axis] * 0.5f32) * grid[3 + axis]
}

#[cube(launch)]
pub fn prepare_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    grid: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    cutoff: f32,
    #[comptime] m: usize,
) {
    let i = ABSOLUTE_POS;
    if i >= k as usize {
        terminate!();
    }
    let o = i * VOX_WIDTH;
    for f in 0..VOX_WIDTH {
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
        let mut span = Array::<f32>::new(6usize);
        let mut good = true;
        for a in 0..3usize {
            let half = cutoff * f32::sqrt(variance(&st, a));
            if !finite(half) {
                good = false;
            }
            let mean = means[3 * i + a];
            let n = grid[a];
            // Voxel index of a coordinate: (x − o)/d + n/2 − ½.
            let first = (mean - half - grid[6 + a]) / grid[3 + a] + n * 0.5f32 - 0.5f32;
            let last = (mean + half - grid[6 + a]) / grid[3 + a] + n * 0.5f32 - 0.5f32;
            crate::cube::math::cell_span(first, last, u32::cast_from(n), &mut span, 2 * a);
            if !(span[2 * a] < span[2 * a + 1]) {
                good = false;
            }
        }
        // Scaled axes w_j = r_j / s_j (r_j the j-th column of R).
        for j in 0..3usize {
            let inv_s = 1.0f32 / st[ST_SCALE + j];
            for a in 0..3usize {
                let w = st[ST_ROT + 3 * a + j] * inv_s;
                if !finite(w) {
                    good = false;
                }
                out[o + 3 + 3 * j + a] = w;
            }
        }
        if good {
            for a in 0..3usize {
                out[o + a] = means[3 * i + a];
                out[o + 12 + a] = span[2 * a];
                out[o + 15 + a] = span[2 * a + 1];
            }
        } else {
            for f in 0..VOX_WIDTH {
                out[o + f] = 0.0f32;
            }
        }
    }
}

/// `−½ q` of the offset `d` from a record's scaled axes `w` (`q = Σ_j (w_j · d)²`, a sum of
/// squares: no cancellation however thin the Gaussian), or `+1` beyond the cut-off.
#[cube]
fn neg_half_q3(w: &Array<f32>, d0: f32, d1: f32, d2: f32, cut2: f32) -> f32 {
    let mut qq = 0.0f32;
    for j in 0..3usize {
        let e = w[3 * j] * d0 + w[3 * j + 1] * d1 + w[3 * j + 2] * d2;
        qq += e * e;
    }
    let mut r = 1.0f32;
    if qq <= cut2 {
        r = -0.5f32 * qq;
    }
    r
}

#[cube(launch)]
pub fn forward_kernel(
    prepared: &Tensor<f32>,
    bounds: &Tensor<f32>,
    densities: &Tensor<f32>,
    grid: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    cut2: f32,
    #[comptime] m: usize,
) {
    let t = ((UNIT_POS_Z * BY + UNIT_POS_Y) * BX + UNIT_POS_X) as usize;
    let nx = u32::cast_from(grid[0]);
    let ny = u32::cast_from(grid[1]);
    let nz = u32::cast_from(grid[2]);
    let mut lo = Array::<f32>::new(3usize);
    let mut hi = Array::<f32>::new(3usize);
    lo[0] = f32::cast_from(CUBE_POS_X * BX);
    lo[1] = f32::cast_from(CUBE_POS_Y * BY);
    lo[2] = f32::cast_from(CUBE_POS_Z * BZ);
    hi[0] = f32::min(lo[0] + f32::cast_from(BX), grid[0]);
    hi[1] = f32::min(lo[1] + f32::cast_from(BY), grid[1]);
    hi[2] = f32::min(lo[2] + f32::cast_from(BZ), grid[2]);
    let ix = CUBE_POS_X * BX + UNIT_POS_X;
    let iy = CUBE_POS_Y * BY + UNIT_POS_Y;
    let iz = CUBE_POS_Z * BZ + UNIT_POS_Z;
    let fx = f32::cast_from(ix);
    let fy = f32::cast_from(iy);
    let fz = f32::cast_from(iz);
    let cx = centre(grid, 0, ix);
    let cy = centre(grid, 1, iy);
    let cz = centre(grid, 2, iz);
    let mut scan = Shared::<[u32]>::new_slice(2 * CHUNK);
    let mut ids = Shared::<[u32]>::new_slice(STEP);
    let mut acc = Array::<f32>::new(m);
    for c in 0..m {
        acc[c] = 0.0f32;
    }
    let mut q = Array::<f32>::new(9usize);
    let kk = k as usize;
    let mut start = 0usize;
    while start < kk {
        // The step's union box (super::step_bounds_kernel): skip the step, uniformly across the
        // cube, if it misses the brick.
        let b = (start / STEP) * 6;
        let mut near = true;
        for a in 0..3usize {
            if !(bounds[b + 2 * a] < hi[a] && bounds[b + 2 * a + 1] > lo[a]) {
                near = false;
            }
        }
        if near {
            let first = start + t * PER_UNIT;
            let mut hits = 0u32;
            for i in 0..PER_UNIT {
                let j = first + i;
                if j < kk {
                    let o = j * VOX_WIDTH;
                    let mut hit = true;
                    for a in 0..3usize {
                        let l = prepared[o + 12 + a];
                        let h = prepared[o + 15 + a];
                        if !(l < h && l < hi[a] && h > lo[a]) {
                            hit = false;
                        }
                    }
                    if hit {
                        hits |= 1u32 << i as u32;
                    }
                }
            }
            let n = stage_chunk(hits, first, t, &mut scan, &mut ids);
            for e in 0..n as usize {
                let gi = ids[e] as usize;
                let r = gi * VOX_WIDTH;
                let inside = fx >= prepared[r + 12]
                    && fx < prepared[r + 15]
                    && fy >= prepared[r + 13]
                    && fy < prepared[r + 16]
                    && fz >= prepared[r + 14]
                    && fz < prepared[r + 17];
                // Only voxels inside the box evaluate: a warp (a SIMD group on lavapipe) whose
                // voxels all miss skips the work.
                if inside {
                    for f in 0..9usize {
                        q[f] = prepared[r + 3 + f];
                    }
                    let nhq = neg_half_q3(
                        &q,
                        cx - prepared[r],
                        cy - prepared[r + 1],
                        cz - prepared[r + 2],
                        cut2,
                    );
                    if nhq <= 0.0f32 {
                        let g = f32::exp(nhq);
                        for c in 0..m {
                            acc[c] += densities[gi * m + c] * g;
                        }
                    }
                }
            }
            sync_cube();
        }
        start += STEP;
    }
    if ix < nx && iy < ny && iz < nz {
        let vol = (nx * ny * nz) as usize;
        let p = ((iz * ny + iy) * nx + ix) as usize;
        for c in 0..m {
            out[c * vol + p] = acc[c];
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
    grid: &Tensor<f32>,
    prepared: &Tensor<f32>,
    grad: &Tensor<f32>,
    g_means: &mut Tensor<f32>,
    g_scales: &mut Tensor<f32>,
    g_rotations: &mut Tensor<f32>,
    g_densities: &mut Tensor<f32>,
    k: u32,
    cut2: f32,
    #[comptime] m: usize,
) {
    let i = ABSOLUTE_POS;
    if i >= k as usize {
        terminate!();
    }
    let o = i * VOX_WIDTH;
    let nx = u32::cast_from(grid[0]);
    let ny = u32::cast_from(grid[1]);
    let nz = u32::cast_from(grid[2]);
    let vol = (nx * ny * nz) as usize;
    let mut sums = Array::<f32>::new(m);
    for c in 0..m {
        sums[c] = 0.0f32;
    }
    // Moments in the Gaussian's frame, e_j = w_j · d (w = uG, u = Σ_c ρ_c ∂L/∂value_c):
    // [Σ w e_j (3), Σ w e_j² (3), Σ w e_j d (3 × 3, row j)]. Sums of e_j² keep the thin axis of a
    // needle or sheet accurate, where world moments d dᵀ contracted with Σ⁻¹ cancel in f32.
    let mut mom = Array::<f32>::new(15usize);
    for e in 0..15usize {
        mom[e] = 0.0f32;
    }
    let mut q = Array::<f32>::new(9usize);
    for f in 0..9usize {
        q[f] = prepared[o + 3 + f];
    }
    let x0 = u32::cast_from(prepared[o + 12]);
    let y0 = u32::cast_from(prepared[o + 13]);
    let z0 = u32::cast_from(prepared[o + 14]);
    let x1 = u32::min(u32::cast_from(prepared[o + 15]), nx);
    let y1 = u32::min(u32::cast_from(prepared[o + 16]), ny);
    let z1 = u32::min(u32::cast_from(prepared[o + 17]), nz);
    let (mx, my, mz) = (prepared[o], prepared[o + 1], prepared[o + 2]);
    let mut e = Array::<f32>::new(3usize);
    let mut z = z0;
    while z < z1 {
        let dz = centre(grid, 2, z) - mz;
        let mut y = y0;
        while y < y1 {
            let dy = centre(grid, 1, y) - my;
            let mut x = x0;
            while x < x1 {
                let dx = centre(grid, 0, x) - mx;
                let mut qq = 0.0f32;
                for j in 0..3usize {
                    e[j] = q[3 * j] * dx + q[3 * j + 1] * dy + q[3 * j + 2] * dz;
                    qq += e[j] * e[j];
                }
                if qq <= cut2 {
                    let g = f32::exp(-0.5f32 * qq);
                    let p = ((z * ny + y) * nx + x) as usize;
                    let mut u = 0.0f32;
                    for c in 0..m {
                        let gc = grad[c * vol + p];
                        sums[c] += gc * g;
                        u += densities[i * m + c] * gc;
                    }
                    let w = u * g;
                    for j in 0..3usize {
                        let we = w * e[j];
                        mom[j] += we;
                        mom[3 + j] += we * e[j];
                        mom[6 + 3 * j] += we * dx;
                        mom[6 + 3 * j + 1] += we * dy;
                        mom[6 + 3 * j + 2] += we * dz;
                    }
                }
                x += 1;
            }
            y += 1;
        }
        z += 1;
    }
    let mut out = Array::<f32>::new(10usize);
    for f in 0..10usize {
        out[f] = 0.0f32;
    }
    let mut good = x0 < x1 && y0 < y1 && z0 < z1;
    let mut st = Array::<f32>::new(ST_LEN);
    if good {
        good = factors(means, scales, rotations, i, &mut st);
    }
    if good {
        // G = exp(−½ Σ_j e_j²), e_j = r_jᵀd / s_j:
        // ∂G/∂mean = G Σ_j e_j w_j, ∂G/∂s_j = G e_j² / s_j, ∂G/∂r_j = −G e_j d / s_j.
        let mut g_rot = Array::<f32>::new(9usize);
        for j in 0..3usize {
            let s = st[ST_SCALE + j];
            for a in 0..3usize {
                out[a] += q[3 * j + a] * mom[j];
                g_rot[3 * a + j] = -mom[6 + 3 * j + a] / s;
            }
            out[3 + j] = mom[3 + j] / s;
        }
        let mut g_quat = Array::<f32>::new(4usize);
        quat_backward(&st, &g_rot, &mut g_quat);
        for f in 0..4usize {
            out[6 + f] = g_quat[f];
        }
        for f in 0..10usize {
            if !finite(out[f]) {
                good = false;
            }
        }
        for c in 0..m {
            if !finite(sums[c]) {
                good = false;
            }
        }
    }
    for a in 0..3usize {
        g_means[3 * i + a] = select(good, out[a], 0.0f32);
        g_scales[3 * i + a] = select(good, out[3 + a], 0.0f32);
    }
    for a in 0..4usize {
        g_rotations[4 * i + a] = select(good, out[6 + a], 0.0f32);
    }
    for c in 0..m {
        g_densities[i * m + c] = select(good, sums[c], 0.0f32);
    }
}
