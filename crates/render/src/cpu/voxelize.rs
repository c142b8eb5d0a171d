//! Voxelization of Gaussians on a regular grid: forward and backward.
//!
//! Works in world units throughout, so the centre gradient is the true `∂L/∂mean`
//! (`Σ w·G·Σ⁻¹d`). Upstream R²-Gaussian's voxelizer scales it by the voxel size instead of its
//! inverse (a factor dV² too small); that quirk is deliberately not reproduced. No absolute skip
//! threshold either: a voxel receives a Gaussian iff it lies within the Mahalanobis cut-off, so
//! tiny densities (1e-8) are not silently dropped.

use rayon::prelude::*;

use super::GaussianSlices;
#[cfg(target_arch = "x86_64")]
use super::lanes::Avx2;
use super::lanes::{LANES, Lanes, Portable, TileGrad, dispatched, has_avx2};
use super::tiles::{Bins, TileBox, tile_span};
use crate::gaussian_math::{self as gm, voxel_backward};
use crate::options::{VoxelGrid, VoxelizeOptions};

/// Voxel tile edge: one lane block per x-row.
pub const TILE: usize = LANES;

/// Elements of a tile buffer per channel: rows are stored `TILE` wide whatever the tile's width
/// (voxels past a grid edge stay 0), so every row is one lane block.
const TILE_VOXELS: usize = TILE * TILE * TILE;

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

/// The per-(splat, tile) constants of the row kernels, and the splat clipped to the tile.
struct VoxBlock<L> {
    /// x offsets `centre − mean` of the tile's lanes.
    dx: L,
    /// `−½ d0` (the x weight of the factored precision).
    neg_half_d0: L,
    /// `−½ cut²` on the splat's clipped lanes and `+∞` elsewhere (one compare applies both).
    neg_half_cut: L,
    /// Clipped voxel box `[lo, hi)` per axis (grid indices).
    lo: [usize; 3],
    hi: [usize; 3],
}

impl<L: Lanes> VoxBlock<L> {
    /// `None` if `s` misses the tile.
    #[inline(always)]
    fn new(s: &VoxSplat, t: &TileCentres, cut2: f32) -> Option<Self> {
        let lo = [0, 1, 2].map(|a| s.lo[a].max(t.lo[a]));
        let hi = [0, 1, 2].map(|a| s.hi[a].min(t.hi[a]));
        if (0..3).any(|a| lo[a] >= hi[a]) {
            return None;
        }
        let lanes = (lo[0] - t.lo[0])..(hi[0] - t.lo[0]);
        let cut: [f32; TILE] = std::array::from_fn(|j| {
            if lanes.contains(&j) {
                -0.5 * cut2
            } else {
                f32::INFINITY
            }
        });
        Some(Self {
            dx: L::load(&t.c[0]).add(L::splat(-s.mean[0])),
            neg_half_d0: L::splat(-0.5 * s.q[0]),
            neg_half_cut: L::load(&cut),
            lo,
            hi,
        })
    }

    /// Visit the splat's rows in the tile: `f(row offset in the tile buffer, dy, dz, G)` with
    /// `G = exp(−½ dᵀΣ⁻¹d)` on the row's lanes (`d = centre − mean`), exactly +0 beyond the
    /// cut-off and outside the clipped box. The form is the factored
    /// `d0 (dx + l01 dy + l02 dz)² + d1 (dy + l12 dz)² + d2 dz²`; a row whose `y, z` part alone
    /// exceeds the cut-off is skipped (every lane of it would be +0).
    #[inline(always)]
    fn rows(
        &self,
        s: &VoxSplat,
        t: &TileCentres,
        cut2: f32,
        mut f: impl FnMut(usize, f32, f32, L),
    ) {
        let [_, l01, l02, d1, l12, d2] = s.q;
        for z in self.lo[2]..self.hi[2] {
            let dz = t.c[2][z - t.lo[2]] - s.mean[2];
            let qz = d2 * dz * dz;
            for y in self.lo[1]..self.hi[1] {
                let dy = t.c[1][y - t.lo[1]] - s.mean[1];
                let e1 = dy + l12 * dz;
                let qyz = d1 * e1 * e1 + qz;
                if (cut2 - qyz).partial_cmp(&0.0) == Some(std::cmp::Ordering::Less) {
                    continue;
                }
                let e0 = self.dx.add(L::splat(l01 * dy + l02 * dz));
                let nhq = self.neg_half_d0.mul(e0).mul_add(e0, L::splat(-0.5 * qyz));
                let g = nhq.exp_neg().keep_le(self.neg_half_cut, nhq);
                f(((z - t.lo[2]) * TILE + (y - t.lo[1])) * TILE, dy, dz, g);
            }
        }
    }
}

/// The `TILE`-lane block of `v` at offset `o`.
#[inline(always)]
fn block(v: &[f32], o: usize) -> &[f32; TILE] {
    v[o..o + TILE].try_into().expect("TILE-wide block")
}

dispatched! {
    /// Forward of splat `s` into the tile buffer `buf` (`[M][TILE_VOXELS]`) with densities `w`.
    fn voxel_forward(s: &VoxSplat, t: &TileCentres, cut2: f32, w: &[f32], buf: &mut [f32]) {
        let Some(vb) = VoxBlock::<L>::new(s, t, cut2) else {
            return;
        };
        let finite = w.iter().all(|w| w.is_finite());
        vb.rows(s, t, cut2, |p, _, _, g| {
            for (c, &w) in w.iter().enumerate() {
                let o = c * TILE_VOXELS + p;
                let add = L::splat(w).mul(g).zero_outside(g, finite);
                let row: &mut [f32; TILE] = (&mut buf[o..o + TILE]).try_into().expect("row");
                L::load(row).add(add).store(row);
            }
        });
    }
}

dispatched! {
    /// Backward partial sums of splat `s` over one tile into `acc`
    /// (`[S_0..S_{M-1}, Σ wG d (3), Σ wG d dᵀ packed xx, xy, xz, yy, yz, zz]`, `w = Σ_c ρ_c g_c`,
    /// `S_c = Σ g_c G`) from the tile's upstream gradient `grad` (`[M][TILE_VOXELS]`).
    ///
    /// Lane accumulators of `wG`, `wG dy`, `wG dz`, `wG dy²`, `wG dy dz`, `wG dz²` (and `g_c G`);
    /// a lane's `dx` is fixed, so the x moments follow at the reduction (`Σ wG dx = Σ_lanes
    /// dx · Σ_rows wG`, and so on). With one channel the sums are of `g G` and `ρ` is applied
    /// after the reduction (`S_0` is then the zeroth moment itself).
    fn voxel_backward_sums(
        s: &VoxSplat,
        t: &TileCentres,
        cut2: f32,
        grad: TileGrad<'_>,
        dens: &[f32],
        lanes: &mut [[f32; TILE]],
        acc: &mut [f64],
    ) {
        let TileGrad { values: gt, finite } = grad;
        let m = dens.len();
        let single = m == 1;
        acc.fill(0.0);
        let Some(vb) = VoxBlock::<L>::new(s, t, cut2) else {
            return;
        };
        let z = L::zero();
        let (mut a, mut ay, mut az, mut ayy, mut ayz, mut azz) = (z, z, z, z, z, z);
        if !single {
            lanes.iter_mut().for_each(|l| *l = [0.0; TILE]);
        }
        vb.rows(s, t, cut2, |p, dy, dz, g| {
            let w = if single {
                g.mul(L::load(block(gt, p))).zero_outside(g, finite)
            } else {
                let mut u = L::zero();
                for (c, &rho) in dens.iter().enumerate() {
                    let gc = L::load(block(gt, c * TILE_VOXELS + p));
                    let sc = g.mul(gc).zero_outside(g, finite);
                    L::load(&lanes[c]).add(sc).store(&mut lanes[c]);
                    u = L::splat(rho).mul_add(gc, u);
                }
                g.mul(u).zero_outside(g, finite)
            };
            let (vy, vz) = (L::splat(dy), L::splat(dz));
            let wy = w.mul(vy);
            let wz = w.mul(vz);
            a = a.add(w);
            ay = ay.add(wy);
            az = az.add(wz);
            ayy = wy.mul_add(vy, ayy);
            ayz = wy.mul_add(vz, ayz);
            azz = wz.mul_add(vz, azz);
        });
        let [sw, x, xx, y, xy, yy] = L::moments(vb.dx, a, ay, ayy);
        let [_, _, _, zs, xz, zz] = L::moments(vb.dx, a, az, azz);
        let yz = ayz.sum();
        if single {
            acc[0] = sw;
        } else {
            for c in 0..m {
                acc[c] = L::load(&lanes[c]).sum();
            }
        }
        let scale = if single { dens[0] as f64 } else { 1.0 };
        let moments = [x, y, zs, xx, xy, xz, yy, yz, zz];
        for (o, v) in acc[m..m + 9].iter_mut().zip(moments) {
            *o = scale * v;
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
            let tc = TileCentres::new(grid, tg.tile_box(t));
            let mut buf = vec![0.0f32; m * TILE_VOXELS];
            for &gi in &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]] {
                let gi = gi as usize;
                let Some(s) = &splats[gi] else { continue };
                let dens = &g.densities[m * gi..m * gi + m];
                voxel_forward(s, &tc, cut2, dens, &mut buf);
            }
            buf
        })
        .collect();
    let [nx, ny, _] = grid.dims;
    for (t, buf) in tiles.iter().enumerate() {
        let (lo, hi) = tg.tile_box(t);
        let tw = hi[0] - lo[0];
        for c in 0..m {
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    let src = c * TILE_VOXELS + ((z - lo[2]) * TILE + (y - lo[1])) * TILE;
                    let dst = c * vol + (z * ny + y) * nx + lo[0];
                    out[dst..dst + tw].copy_from_slice(&buf[src..src + tw]);
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
            // The tile's upstream gradient, TILE-wide rows: [M][TILE_VOXELS].
            let mut gt = vec![0.0f32; m * TILE_VOXELS];
            for c in 0..m {
                for z in lo[2]..hi[2] {
                    for y in lo[1]..hi[1] {
                        let src = c * vol + (z * ny + y) * nx + lo[0];
                        let dst = c * TILE_VOXELS + ((z - lo[2]) * TILE + (y - lo[1])) * TILE;
                        gt[dst..dst + tw].copy_from_slice(&grad[src..src + tw]);
                    }
                }
            }
            let tile_grad = TileGrad::new(&gt);
            let tc = TileCentres::new(grid, tb);
            let list = &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]];
            let mut lanes = vec![[0.0f32; TILE]; m];
            for (j, &gi) in list.iter().enumerate() {
                let gi = gi as usize;
                let acc = &mut out[j * stride..(j + 1) * stride];
                let Some(s) = &splats[gi] else { continue };
                let dens = &g.densities[m * gi..m * gi + m];
                voxel_backward_sums(s, &tc, cut2, tile_grad, dens, &mut lanes, acc);
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
