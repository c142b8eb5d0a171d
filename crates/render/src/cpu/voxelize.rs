//! Voxelization of Gaussians on a regular grid: forward and backward.

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
    (0..g.len())
        .into_par_iter()
        .map(|i| {
            if g.densities_of(i).is_none() {
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

/// Visit the voxels of `s` inside the tile box within the cut-off: `f(local_index, d, G)` with
/// `d = centre − mean` and `G = exp(−½ dᵀ Σ⁻¹ d)`; local index is `[z][y][x]` within the tile.
#[inline(always)]
fn voxels(
    s: &VoxSplat,
    grid: &VoxelGrid,
    tile: &([usize; 3], [usize; 3]),
    cut2: f32,
    mut f: impl FnMut(usize, [f32; 3], f32),
) {
    let (tlo, thi) = tile;
    let lo = [0, 1, 2].map(|a| s.lo[a].max(tlo[a]));
    let hi = [0, 1, 2].map(|a| s.hi[a].min(thi[a]));
    let (tw, th) = (thi[0] - tlo[0], thi[1] - tlo[1]);
    let [d0, l01, l02, d1, l12, d2] = s.q;
    for z in lo[2]..hi[2] {
        let dz = (grid.centre(2, z) as f32) - s.mean[2];
        let qz = d2 * dz * dz;
        for y in lo[1]..hi[1] {
            let dy = (grid.centre(1, y) as f32) - s.mean[1];
            let e1 = dy + l12 * dz;
            let qyz = d1 * e1 * e1 + qz;
            let cx = l01 * dy + l02 * dz;
            let row = ((z - tlo[2]) * th + (y - tlo[1])) * tw;
            for x in lo[0]..hi[0] {
                let dx = (grid.centre(0, x) as f32) - s.mean[0];
                let e0 = dx + cx;
                let q = d0 * e0 * e0 + qyz;
                if q <= cut2 {
                    f(row + x - tlo[0], [dx, dy, dz], super::exp_neg(-0.5 * q));
                }
            }
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
    let bins = Bins::new(tg.tiles, &boxes);
    let tiles: Vec<Vec<f32>> = (0..tg.n_tiles())
        .into_par_iter()
        .map(|t| {
            let tb = tg.tile_box(t);
            let n: usize = (0..3).map(|a| tb.1[a] - tb.0[a]).product();
            let mut buf = vec![0.0f32; m * n];
            for &gi in &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]] {
                let gi = gi as usize;
                let Some(s) = &splats[gi] else { continue };
                let dens = &g.densities[m * gi..m * gi + m];
                if m == 1 {
                    let w = dens[0];
                    voxels(s, grid, &tb, cut2, |p, _, e| buf[p] += w * e);
                } else {
                    voxels(s, grid, &tb, cut2, |p, _, e| {
                        for c in 0..m {
                            buf[c * n + p] += dens[c] * e;
                        }
                    });
                }
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
            let list = &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]];
            let mut sc = vec![0.0f32; m];
            for (j, &gi) in list.iter().enumerate() {
                let gi = gi as usize;
                let Some(s) = &splats[gi] else { continue };
                let dens = &g.densities[m * gi..m * gi + m];
                sc.iter_mut().for_each(|v| *v = 0.0);
                let mut sums = [0.0f32; 9];
                voxels(s, grid, &tb, cut2, |p, d, e| {
                    let mut wg = 0.0f32;
                    for c in 0..m {
                        let ge = gt[c * n + p] * e;
                        sc[c] += ge;
                        wg += dens[c] * ge;
                    }
                    sums[0] += wg * d[0];
                    sums[1] += wg * d[1];
                    sums[2] += wg * d[2];
                    sums[3] += wg * d[0] * d[0];
                    sums[4] += wg * d[0] * d[1];
                    sums[5] += wg * d[0] * d[2];
                    sums[6] += wg * d[1] * d[1];
                    sums[7] += wg * d[1] * d[2];
                    sums[8] += wg * d[2] * d[2];
                });
                let acc = &mut out[j * stride..(j + 1) * stride];
                for c in 0..m {
                    acc[c] = sc[c] as f64;
                }
                for q in 0..9 {
                    acc[m + q] = sums[q] as f64;
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
