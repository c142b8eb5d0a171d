//! Voxelization of Gaussians on a regular grid: forward and backward.
//!
//! Works in world units throughout, so the centre gradient is the true `∂L/∂mean`
//! (`Σ w·G·Σ⁻¹d`). Upstream R²-Gaussian's voxelizer scales it by the voxel size instead of its
//! inverse (a factor dV² too small); that quirk is deliberately not reproduced. No absolute skip
//! threshold either: a voxel receives a Gaussian iff it lies within the Mahalanobis cut-off, so
//! tiny densities (1e-8) are not silently dropped.

use rayon::prelude::*;

use super::GaussianSlices;
use super::tiles::{Bins, TileBox, tile_span};
use crate::gaussian_math::{self as gm, voxel_backward};
use crate::options::{VoxelGrid, VoxelizeOptions};

/// Voxel tile edge.
pub const TILE: usize = 8;

/// Gradients of a voxelization with respect to every input, row-major like the inputs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VoxelizeGrads {
    pub means: Vec<f32>,
    pub scales: Vec<f32>,
    pub rotations: Vec<f32>,
    pub densities: Vec<f32>,
}

/// A Gaussian reduced to what the voxel loop reads (f32), with its clamped voxel box.
#[derive(Clone, Copy, Debug)]
struct VoxSplat {
    mean: [f32; 3],
    /// Factored precision `[d0, l01, l02, d1, l12, d2]` (see [`gm::Quad3`]).
    q: [f32; 6],
    /// Voxel box `[lo, hi)` per axis `[x, y, z]`.
    lo: [usize; 3],
    hi: [usize; 3],
}

struct TileGrid {
    dims: [usize; 3],
    tiles: [usize; 3],
}

impl TileGrid {
    fn new(grid: &VoxelGrid) -> Self {
        Self {
            dims: grid.dims,
            tiles: grid.dims.map(|n| n.div_ceil(TILE)),
        }
    }

    fn n_tiles(&self) -> usize {
        self.tiles.iter().product()
    }

    /// Voxel box `[lo, hi)` of tile `t`.
    fn tile_box(&self, t: usize) -> ([usize; 3], [usize; 3]) {
        let tx = t % self.tiles[0];
        let ty = (t / self.tiles[0]) % self.tiles[1];
        let tz = t / (self.tiles[0] * self.tiles[1]);
        let lo = [tx * TILE, ty * TILE, tz * TILE];
        let hi = [0, 1, 2].map(|a| (lo[a] + TILE).min(self.dims[a]));
        (lo, hi)
    }
}

fn prepare(
    g: &GaussianSlices,
    grid: &VoxelGrid,
    cutoff: f64,
) -> (Vec<Option<VoxSplat>>, Vec<Option<TileBox>>) {
    // Voxel-centre range per axis: a Gaussian whose cut-off reach (≤ cutoff · largest scale)
    // misses it is rejected before any f64 shape work — most of them for a small TV patch.
    let first = [0, 1, 2].map(|a| grid.centre(a, 0));
    let last = [0, 1, 2].map(|a| grid.centre(a, grid.dims[a] - 1));
    (0..g.len())
        .into_par_iter()
        .map(|i| {
            let reach = cutoff
                * g.scales[3 * i..3 * i + 3]
                    .iter()
                    .fold(0.0f64, |m, &v| m.max(v.abs() as f64));
            let far = (0..3).any(|a| {
                let c = g.means[3 * i + a] as f64;
                c + reach < first[a] || c - reach > last[a]
            });
            if far || g.densities_of(i).is_none() {
                return (None, None);
            }
            let Some(s) = gm::voxel_splat(&g.geom(i), cutoff) else {
                return (None, None);
            };
            let mut lo = [0; 3];
            let mut hi = [0; 3];
            let mut tlo = [0; 3];
            let mut thi = [0; 3];
            for a in 0..3 {
                // Voxel i's centre is offset + (i + ½ − n/2)·d, so i = (x − offset)/d + n/2 − ½.
                let to_index =
                    |x: f64| (x - grid.offset[a]) / grid.voxel[a] + grid.dims[a] as f64 / 2.0 - 0.5;
                let first = to_index(s.mean[a] - s.half_extent[a]);
                let last = to_index(s.mean[a] + s.half_extent[a]);
                let Some((l, h, tl, th)) = tile_span(first, last, grid.dims[a], TILE) else {
                    return (None, None);
                };
                (lo[a], hi[a], tlo[a], thi[a]) = (l, h, tl, th);
            }
            let q = s.quad;
            let vs = VoxSplat {
                mean: s.mean.map(|v| v as f32),
                q: [q.d0, q.l01, q.l02, q.d1, q.l12, q.d2].map(|v| v as f32),
                lo,
                hi,
            };
            if vs.q.iter().all(|v| v.is_finite()) {
                (Some(vs), Some(TileBox { lo: tlo, hi: thi }))
            } else {
                (None, None)
            }
        })
        .unzip()
}

/// Voxel-centre coordinates of one tile, per axis (f32, world units).
struct TileCentres {
    lo: [usize; 3],
    hi: [usize; 3],
    c: [[f32; TILE]; 3],
}

impl TileCentres {
    fn new(grid: &VoxelGrid, tile: ([usize; 3], [usize; 3])) -> Self {
        let mut c = [[0.0f32; TILE]; 3];
        for a in 0..3 {
            for (j, v) in c[a].iter_mut().enumerate() {
                *v = grid.centre(a, tile.0[a] + j) as f32;
            }
        }
        Self {
            lo: tile.0,
            hi: tile.1,
            c,
        }
    }
}

/// Visit the x-rows of `s` inside the tile: `f(local_row_start, x0, [dy, dz], e)` where `e[j]`
/// is `G = exp(−½ dᵀ Σ⁻¹ d)` at tile-local voxel `x0 + j` (0 beyond the cut-off),
/// `d = centre − mean`, local indices `[z][y][x]` within the tile. Rows are evaluated
/// branch-free over the whole tile width so they vectorise.
#[inline(always)]
fn voxel_rows(
    s: &VoxSplat,
    t: &TileCentres,
    cut2: f32,
    mut f: impl FnMut(usize, usize, [f32; 2], &[f32]),
) {
    let lo = [0, 1, 2].map(|a| s.lo[a].max(t.lo[a]));
    let hi = [0, 1, 2].map(|a| s.hi[a].min(t.hi[a]));
    if lo[0] >= hi[0] {
        return;
    }
    let (tw, th) = (t.hi[0] - t.lo[0], t.hi[1] - t.lo[1]);
    let [d0, l01, l02, d1, l12, d2] = s.q;
    let mut dxs = [0.0f32; TILE];
    for (d, c) in dxs.iter_mut().zip(&t.c[0]) {
        *d = c - s.mean[0];
    }
    let (x0, n) = (lo[0] - t.lo[0], hi[0] - lo[0]);
    let mut e = [0.0f32; TILE];
    for z in lo[2]..hi[2] {
        let dz = t.c[2][z - t.lo[2]] - s.mean[2];
        let qz = d2 * dz * dz;
        for y in lo[1]..hi[1] {
            let dy = t.c[1][y - t.lo[1]] - s.mean[1];
            let e1 = dy + l12 * dz;
            let qyz = d1 * e1 * e1 + qz;
            let cx = l01 * dy + l02 * dz;
            for (ej, dx) in e.iter_mut().zip(&dxs) {
                let e0 = dx + cx;
                let q = d0 * e0 * e0 + qyz;
                let v = super::exp_neg(-0.5 * q);
                *ej = if q <= cut2 { v } else { 0.0 };
            }
            let row = ((z - t.lo[2]) * th + (y - t.lo[1])) * tw;
            f(row + x0, x0, [dy, dz], &e[x0..x0 + n]);
        }
    }
}

/// Density on the grid, `[M, nz, ny, nx]`: `Σ_i ρ_i,c · exp(−½ dᵀΣ_i⁻¹d)` at voxel centres, each
/// Gaussian cut off at `cutoff` Mahalanobis units.
pub fn voxelize_forward(g: &GaussianSlices, grid: &VoxelGrid, opts: &VoxelizeOptions) -> Vec<f32> {
    let m = g.channels;
    let vol = grid.len();
    let mut out = vec![0.0f32; m * vol];
    if g.is_empty() || vol == 0 || m == 0 {
        return out;
    }
    let cut2 = (opts.cutoff * opts.cutoff) as f32;
    let tg = TileGrid::new(grid);
    let (splats, boxes) = prepare(g, grid, opts.cutoff);
    let bins = Bins::tile_lists(tg.tiles, &boxes);
    let tiles: Vec<Vec<f32>> = (0..tg.n_tiles())
        .into_par_iter()
        .map(|t| {
            let tb = tg.tile_box(t);
            let tc = TileCentres::new(grid, tb);
            let n: usize = (0..3).map(|a| tb.1[a] - tb.0[a]).product();
            let mut buf = vec![0.0f32; m * n];
            for &gi in &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]] {
                let gi = gi as usize;
                let Some(s) = &splats[gi] else { continue };
                let dens = &g.densities[m * gi..m * gi + m];
                voxel_rows(s, &tc, cut2, |p, _, _, e| {
                    for c in 0..m {
                        let w = dens[c];
                        for (b, e) in buf[c * n + p..c * n + p + e.len()].iter_mut().zip(e) {
                            *b += w * e;
                        }
                    }
                });
            }
            buf
        })
        .collect();
    let [nx, ny, _] = grid.dims;
    for (t, buf) in tiles.iter().enumerate() {
        let (lo, hi) = tg.tile_box(t);
        let tw = hi[0] - lo[0];
        let n: usize = (0..3).map(|a| hi[a] - lo[a]).product();
        for c in 0..m {
            let mut p = c * n;
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    let dst = c * vol + (z * ny + y) * nx + lo[0];
                    out[dst..dst + tw].copy_from_slice(&buf[p..p + tw]);
                    p += tw;
                }
            }
        }
    }
    out
}

/// Gradients of `L` given `grad = ∂L/∂volume` (`[M, nz, ny, nx]`).
pub fn voxelize_backward(
    g: &GaussianSlices,
    grid: &VoxelGrid,
    opts: &VoxelizeOptions,
    grad: &[f32],
) -> VoxelizeGrads {
    let k = g.len();
    let m = g.channels;
    let vol = grid.len();
    let mut total = VoxelizeGrads {
        means: vec![0.0; 3 * k],
        scales: vec![0.0; 3 * k],
        rotations: vec![0.0; 4 * k],
        densities: vec![0.0; m * k],
    };
    if k == 0 || vol == 0 || m == 0 {
        return total;
    }
    let cut2 = (opts.cutoff * opts.cutoff) as f32;
    let tg = TileGrid::new(grid);
    let (splats, boxes) = prepare(g, grid, opts.cutoff);
    let bins = Bins::new(tg.tiles, &boxes);
    // Per slot: [S_0..S_{M-1}, Σ wG d (3), Σ wG d dᵀ packed (6)], w = Σ_c ρ_c g_c.
    let stride = m + 9;
    let mut slots = vec![0.0f64; bins.isects() * stride];
    let [nx, ny, _] = grid.dims;
    bins.split_per_tile(&mut slots, stride)
        .into_par_iter()
        .enumerate()
        .for_each(|(t, out)| {
            let tb = tg.tile_box(t);
            let (lo, hi) = tb;
            let tw = hi[0] - lo[0];
            let n: usize = (0..3).map(|a| hi[a] - lo[a]).product();
            let mut gt = vec![0.0f32; m * n];
            for c in 0..m {
                let mut p = 0;
                for z in lo[2]..hi[2] {
                    for y in lo[1]..hi[1] {
                        let src = c * vol + (z * ny + y) * nx + lo[0];
                        gt[c * n + p..c * n + p + tw].copy_from_slice(&grad[src..src + tw]);
                        p += tw;
                    }
                }
            }
            let tc = TileCentres::new(grid, tb);
            let list = &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]];
            // Per-lane (x) partial sums, reduced once per pair: [S_0..S_{M-1}] and the moments
            // [x, y, z, xx, xy, xz, yy, yz, zz] of w·G, w = Σ_c ρ_c g_c.
            let mut lanes = vec![[0.0f32; TILE]; m];
            let mut mom = [[0.0f32; TILE]; 9];
            for (j, &gi) in list.iter().enumerate() {
                let gi = gi as usize;
                let Some(s) = &splats[gi] else { continue };
                let dens = &g.densities[m * gi..m * gi + m];
                let dxs: [f32; TILE] = std::array::from_fn(|i| tc.c[0][i] - s.mean[0]);
                voxel_rows(s, &tc, cut2, |p, x0, [dy, dz], e| {
                    let k = e.len().min(TILE);
                    let mut wge = [0.0f32; TILE];
                    for c in 0..m {
                        let gc = &gt[c * n + p..c * n + p + k];
                        let rho = dens[c];
                        let lane = &mut lanes[c];
                        for i in 0..k {
                            let ge = gc[i] * e[i];
                            lane[i] += ge;
                            wge[i] += rho * ge;
                        }
                    }
                    let dx = &dxs[x0..x0 + k];
                    let [lx, ly, lz, lxx, lxy, lxz, lyy, lyz, lzz] = &mut mom;
                    for i in 0..k {
                        let w = wge[i];
                        let wx = w * dx[i];
                        let wy = w * dy;
                        let wz = w * dz;
                        lx[i] += wx;
                        ly[i] += wy;
                        lz[i] += wz;
                        lxx[i] += wx * dx[i];
                        lxy[i] += wx * dy;
                        lxz[i] += wx * dz;
                        lyy[i] += wy * dy;
                        lyz[i] += wy * dz;
                        lzz[i] += wz * dz;
                    }
                });
                let acc = &mut out[j * stride..(j + 1) * stride];
                for c in 0..m {
                    acc[c] = lanes[c].iter().map(|&v| v as f64).sum();
                    lanes[c] = [0.0; TILE];
                }
                // Packed [x, y, z, xx, xy, xz, yy, yz, zz].
                for q in 0..9 {
                    acc[m + q] = mom[q].iter().map(|&v| v as f64).sum();
                    mom[q] = [0.0; TILE];
                }
            }
        });
    let results: Vec<Option<([f64; 10], Vec<f64>)>> = (0..k)
        .into_par_iter()
        .map(|i| {
            let isects = &bins.gaussian_isects[bins.gaussian_start[i]..bins.gaussian_start[i + 1]];
            if isects.is_empty() {
                return None;
            }
            let mut sum = vec![0.0f64; stride];
            for &slot in isects {
                for (a, b) in sum
                    .iter_mut()
                    .zip(&slots[slot * stride..(slot + 1) * stride])
                {
                    *a += b;
                }
            }
            let sum_d = [sum[m], sum[m + 1], sum[m + 2]];
            let p = &sum[m + 3..m + 9];
            let sum_dd = [[p[0], p[1], p[2]], [p[1], p[3], p[4]], [p[2], p[4], p[5]]];
            let geo = voxel_backward(&g.geom(i), sum_d, &sum_dd);
            let mut flat = [0.0f64; 10];
            flat[..3].copy_from_slice(&geo.mean);
            flat[3..6].copy_from_slice(&geo.scale);
            flat[6..].copy_from_slice(&geo.quat);
            let dens = sum[..m].to_vec();
            flat.iter()
                .chain(&dens)
                .all(|x| x.is_finite())
                .then_some((flat, dens))
        })
        .collect();
    for (i, r) in results.into_iter().enumerate() {
        let Some((flat, dens)) = r else { continue };
        for q in 0..3 {
            total.means[3 * i + q] = flat[q] as f32;
            total.scales[3 * i + q] = flat[3 + q] as f32;
        }
        for q in 0..4 {
            total.rotations[4 * i + q] = flat[6 + q] as f32;
        }
        for c in 0..m {
            total.densities[m * i + c] = dens[c] as f32;
        }
    }
    total
}
