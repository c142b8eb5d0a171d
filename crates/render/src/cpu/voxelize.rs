//! Voxelization of Gaussians on a regular grid: forward and backward.
//!
//! Works in world units throughout, so the centre gradient is the true `∂L/∂mean`
//! (`Σ w·G·Σ⁻¹d`). Upstream R²-Gaussian's voxelizer scales it by the voxel size instead of its
//! inverse (a factor dV² too small); that quirk is deliberately not reproduced. No absolute skip
//! threshold either: a voxel receives a Gaussian iff it lies within the Mahalanobis cut-off, so
//! tiny densities (1e-8) are not silently dropped.
//!
//! Both passes walk a Gaussian's voxel box row by row (x fastest), in lane blocks that start at
//! the box's own first x: a row no wider than a block is evaluated once, wherever it lies (a
//! grid-aligned tile would split most rows of a 3σ box in two). Rows whose `y, z` part alone
//! exceeds the cut-off are skipped.
//! * The forward pass bins Gaussians into slabs of [`SLAB`] z-slices and owns one slab per task;
//!   a slab sums its Gaussians in index order, so every voxel's sum has the same order (and
//!   value) however the grid is split.
//! * The backward pass owns one Gaussian per task and reads the upstream gradient along the
//!   same rows: its sums are its own, so nothing is stored per (Gaussian, slab) or gathered.

use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
use super::lanes::Avx2;
use super::lanes::{LANES, Lanes, Portable, RowBatches, UpstreamGrad, dispatched, drain, has_avx2};
use super::padded::PaddedRows;
use super::tiles::{Bins, TileBox, tile_span};
use super::{GaussianSlices, grad_row, zeros};
use crate::gaussian_math::{self as gm, GeomGrad, voxel_backward};
use crate::options::{VoxelGrid, VoxelizeOptions};

/// z-slices per forward task.
const SLAB: usize = 4;

/// Rows summed in f32 lanes before the backward moments are widened into f64 (bounds the f32
/// rounding of a large Gaussian's sums to that of 64 terms per lane).
const FLUSH_ROWS: usize = 64;

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

impl VoxSplat {
    /// The first x of each lane block covering the box.
    fn blocks(&self) -> impl Iterator<Item = usize> {
        (self.lo[0]..self.hi[0]).step_by(LANES)
    }
}

/// Voxel-centre range of a grid per axis and the cut-off, for [`near_flags`].
#[derive(Clone, Copy)]
struct Reach {
    first: [f64; 3],
    last: [f64; 3],
    cutoff: f64,
}

/// Gaussians per task of [`prepare`]'s reach test.
const REACH_CHUNK: usize = 512;

dispatched! {
    /// `near[j]`: whether Gaussian `start + j`'s cut-off reach (≤ cutoff · largest scale) meets
    /// the grid's voxel-centre range on every axis. Branch-free (`|`, not `||`): which axis a
    /// far Gaussian misses on is random.
    fn near_flags(g: &GaussianSlices<'_>, r: Reach, start: usize, near: &mut [bool]) {
        let n = near.len();
        let means = g.means[3 * start..3 * (start + n)].chunks_exact(3);
        let scales = g.scales[3 * start..3 * (start + n)].chunks_exact(3);
        for ((o, c), s) in near.iter_mut().zip(means).zip(scales) {
            let reach = r.cutoff * s.iter().fold(0.0f64, |m, &v| m.max(v.abs() as f64));
            let far = (0..3).fold(false, |far, a| {
                let x = c[a] as f64;
                far | (x + reach < r.first[a]) | (x - reach > r.last[a])
            });
            *o = !far;
        }
    }
}

/// The Gaussians whose cut-off box meets the grid, in index order, each with its index and
/// voxel splat: a small TV patch meets a few per cent of them, so the passes walk this list
/// rather than one slot per Gaussian.
fn prepare(g: &GaussianSlices, grid: &VoxelGrid, cutoff: f64) -> Vec<(usize, VoxSplat)> {
    // A Gaussian whose cut-off reach misses the voxel centres is rejected before any f64
    // shape work — most of them for a small TV patch.
    let reach = Reach {
        first: [0, 1, 2].map(|a| grid.centre(a, 0)),
        last: [0, 1, 2].map(|a| grid.centre(a, grid.dims[a] - 1)),
        cutoff,
    };
    let k = g.len();
    (0..k.div_ceil(REACH_CHUNK))
        .into_par_iter()
        .flat_map_iter(|c| {
            let start = c * REACH_CHUNK;
            let n = REACH_CHUNK.min(k - start);
            let mut near = [false; REACH_CHUNK];
            near_flags(g, reach, start, &mut near[..n]);
            (0..n).filter(move |&j| near[j]).map(move |j| start + j)
        })
        .filter_map(|i| {
            g.densities_of(i)?;
            let s = gm::voxel_splat(&g.geom(i), cutoff)?;
            let mut lo = [0; 3];
            let mut hi = [0; 3];
            for a in 0..3 {
                // Voxel i's centre is offset + (i + ½ − n/2)·d, so i = (x − offset)/d + n/2 − ½.
                let to_index =
                    |x: f64| (x - grid.offset[a]) / grid.voxel[a] + grid.dims[a] as f64 / 2.0 - 0.5;
                let first = to_index(s.mean[a] - s.half_extent[a]);
                let last = to_index(s.mean[a] + s.half_extent[a]);
                (lo[a], hi[a], _, _) = tile_span(first, last, grid.dims[a], 1)?;
            }
            let q = s.quad;
            let vs = VoxSplat {
                mean: s.mean.map(|v| v as f32),
                q: [q.d0, q.l01, q.l02, q.d1, q.l12, q.d2].map(|v| v as f32),
                lo,
                hi,
            };
            vs.q.iter().all(|v| v.is_finite()).then_some((i, vs))
        })
        .collect()
}

/// Voxel-centre coordinates per axis (f32, world units); x runs `LANES` past the grid, so a lane
/// block starting at any voxel of a row has its centres.
struct Centres([Vec<f32>; 3]);

impl Centres {
    fn new(grid: &VoxelGrid) -> Self {
        Self([0, 1, 2].map(|a| {
            let n = grid.dims[a] + if a == 0 { LANES } else { 0 };
            (0..n).map(|i| grid.centre(a, i) as f32).collect()
        }))
    }
}

/// Where the voxels of slices `z0..` lie in a row-padded volume (`[M][z][y][nx + LANES]`).
#[derive(Clone, Copy)]
struct Slices {
    rows: PaddedRows,
    ny: usize,
    z0: usize,
}

impl Slices {
    /// Slices `[z0, z1)` of `grid`.
    fn new(grid: &VoxelGrid, z0: usize, z1: usize) -> Self {
        let [nx, ny, _] = grid.dims;
        Self {
            rows: PaddedRows::new(nx, (z1 - z0) * ny),
            ny,
            z0,
        }
    }

    /// Offset of voxel `(x, y, z)` of channel `c`.
    #[inline(always)]
    fn at(&self, c: usize, x: usize, y: usize, z: usize) -> usize {
        self.rows.at(c, (z - self.z0) * self.ny + y, x)
    }
}

/// What the row kernels of one pass read besides the splat: the voxel centres, the padded
/// layout of the volume they write or read, and the squared cut-off.
#[derive(Clone, Copy)]
struct Pass<'a> {
    centres: &'a Centres,
    pad: Slices,
    cut2: f32,
}

/// The per-(splat, lane block) constants of the row kernels.
struct VoxBlock<L> {
    /// x offsets `centre − mean` of the block's lanes.
    dx: L,
    /// `−½ d0` (the x weight of the factored precision).
    neg_half_d0: L,
    /// `−½ cut²` on the lanes inside the splat's box and `+∞` elsewhere (one compare applies
    /// both).
    neg_half_cut: L,
}

impl<L: Lanes> VoxBlock<L> {
    /// The block of `s` whose first lane is voxel `x0`.
    #[inline(always)]
    fn new(s: &VoxSplat, pass: Pass<'_>, x0: usize) -> Self {
        let inside = s.hi[0] - x0;
        let cut: [f32; LANES] = std::array::from_fn(|j| {
            if j < inside {
                -0.5 * pass.cut2
            } else {
                f32::INFINITY
            }
        });
        let xs: &[f32; LANES] = pass.centres.0[0][x0..x0 + LANES]
            .try_into()
            .expect("padded centres");
        Self {
            dx: L::load(xs).add(L::splat(-s.mean[0])),
            neg_half_d0: L::splat(-0.5 * s.q[0]),
            neg_half_cut: L::load(&cut),
        }
    }

    /// Visit the splat's rows with `z` in `zs`: `f(y, z, dy, dz, G)` with
    /// `G = exp(−½ dᵀΣ⁻¹d)` on the block's lanes (`d = centre − mean`), exactly +0 beyond the
    /// cut-off and outside the box. The form is the factored
    /// `d0 (dx + l01 dy + l02 dz)² + d1 (dy + l12 dz)² + d2 dz²`; a row whose `y, z` part alone
    /// exceeds the cut-off is skipped (every lane of it would be +0).
    #[inline(always)]
    fn rows(
        &self,
        s: &VoxSplat,
        pass: Pass<'_>,
        zs: std::ops::Range<usize>,
        mut f: impl FnMut(usize, usize, f32, f32, L),
    ) {
        let (c, cut2) = (pass.centres, pass.cut2);
        let [_, l01, l02, d1, l12, d2] = s.q;
        for z in zs {
            let dz = c.0[2][z] - s.mean[2];
            let qz = d2 * dz * dz;
            for y in s.lo[1]..s.hi[1] {
                let dy = c.0[1][y] - s.mean[1];
                let e1 = dy + l12 * dz;
                let qyz = d1 * e1 * e1 + qz;
                if (cut2 - qyz).partial_cmp(&0.0) == Some(std::cmp::Ordering::Less) {
                    continue;
                }
                let e0 = self.dx.add(L::splat(l01 * dy + l02 * dz));
                let nhq = self.neg_half_d0.mul(e0).mul_add(e0, L::splat(-0.5 * qyz));
                let g = nhq.exp_neg().keep_le(self.neg_half_cut, nhq);
                f(y, z, dy, dz, g);
            }
        }
    }
}

/// The `LANES`-wide block of `v` at offset `o`.
#[inline(always)]
fn block(v: &[f32], o: usize) -> &[f32; LANES] {
    v[o..o + LANES].try_into().expect("lane block")
}

dispatched! {
    /// Forward of splat `s`'s rows with `z` in `zs` into the slab buffer `buf` (laid out by
    /// `pass.pad`) with densities `w`.
    fn voxel_forward(
        s: &VoxSplat,
        pass: Pass<'_>,
        zs: std::ops::Range<usize>,
        w: &[f32],
        buf: &mut [f32],
    ) {
        let finite = w.iter().all(|w| w.is_finite());
        for x0 in s.blocks() {
            let vb = VoxBlock::<L>::new(s, pass, x0);
            vb.rows(s, pass, zs.clone(), |y, z, _, _, g| {
                for (ch, &w) in w.iter().enumerate() {
                    let o = pass.pad.at(ch, x0, y, z);
                    let add = L::splat(w).mul(g).zero_outside(g, finite);
                    let row: &mut [f32; LANES] =
                        (&mut buf[o..o + LANES]).try_into().expect("row");
                    L::load(row).add(add).store(row);
                }
            });
        }
    }
}

/// Widen the f32 lane sums of `w = Σ_c ρ_c g_c G` moments (and the per-channel `g_c G` in
/// `lanes`) into `acc` and zero them; `dx` are the block's x offsets (fixed per lane, so the x
/// moments follow here: `Σ wG dx = Σ_lanes dx · Σ_rows wG`, and so on). With one channel the
/// sums are of `g G`, and `ρ` is applied here (`S_0` is then the zeroth moment itself).
#[inline(always)]
fn flush<L: Lanes>(
    dx: L,
    sums: &mut [L; 6],
    lanes: &mut [[f32; LANES]],
    dens: &[f32],
    acc: &mut [f64],
) {
    let m = dens.len();
    let [a, ay, az, ayy, ayz, azz] = *sums;
    let [sw, x, xx, y, xy, yy] = L::moments(dx, a, ay, ayy);
    let [_, _, _, zs, xz, zz] = L::moments(dx, a, az, azz);
    let yz = ayz.sum();
    let scale = if m == 1 {
        acc[0] += sw;
        dens[0] as f64
    } else {
        drain::<L>(lanes, acc);
        1.0
    };
    let moments = [x, y, zs, xx, xy, xz, yy, yz, zz];
    for (o, v) in acc[m..m + 9].iter_mut().zip(moments) {
        *o += scale * v;
    }
    *sums = [L::zero(); 6];
}

dispatched! {
    /// Backward sums of splat `s` over its lane block starting at voxel `x0`, added to `acc`
    /// (`[S_0..S_{M-1}, Σ wG d (3), Σ wG d dᵀ packed xx, xy, xz, yy, yz, zz]`, `w = Σ_c ρ_c g_c`,
    /// `S_c = Σ g_c G`) from the upstream gradient `grad` (laid out by `pass.pad`); `lanes` is
    /// scratch of `M` lane blocks, zero on entry and on return.
    ///
    /// Lane accumulators of `wG`, `wG dy`, `wG dz`, `wG dy²`, `wG dy dz`, `wG dz²` (and `g_c G`),
    /// widened into f64 every [`FLUSH_ROWS`] rows.
    fn voxel_backward_sums(
        s: &VoxSplat,
        pass: Pass<'_>,
        x0: usize,
        grad: UpstreamGrad<'_>,
        dens: &[f32],
        lanes: &mut [[f32; LANES]],
        acc: &mut [f64],
    ) {
        let UpstreamGrad { values: gv, finite } = grad;
        let single = dens.len() == 1;
        let pad = pass.pad;
        let vb = VoxBlock::<L>::new(s, pass, x0);
        let mut sums = [L::zero(); 6];
        let mut batches = RowBatches::new(FLUSH_ROWS);
        vb.rows(s, pass, s.lo[2]..s.hi[2], |y, z, dy, dz, g| {
            let w = if single {
                g.mul(L::load(block(gv, pad.at(0, x0, y, z)))).zero_outside(g, finite)
            } else {
                let mut u = L::zero();
                for (ch, &rho) in dens.iter().enumerate() {
                    let gc = L::load(block(gv, pad.at(ch, x0, y, z)));
                    let sc = g.mul(gc).zero_outside(g, finite);
                    L::load(&lanes[ch]).add(sc).store(&mut lanes[ch]);
                    u = L::splat(rho).mul_add(gc, u);
                }
                g.mul(u).zero_outside(g, finite)
            };
            let (vy, vz) = (L::splat(dy), L::splat(dz));
            let wy = w.mul(vy);
            let wz = w.mul(vz);
            let [a, ay, az, ayy, ayz, azz] = &mut sums;
            *a = a.add(w);
            *ay = ay.add(wy);
            *az = az.add(wz);
            *ayy = wy.mul_add(vy, *ayy);
            *ayz = wy.mul_add(vz, *ayz);
            *azz = wz.mul_add(vz, *azz);
            if batches.due() {
                flush(vb.dx, &mut sums, lanes, dens, acc);
            }
        });
        if batches.pending() {
            flush(vb.dx, &mut sums, lanes, dens, acc);
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
    let splats = prepare(g, grid, opts.cutoff);
    let centres = Centres::new(grid);
    let [_, ny, nz] = grid.dims;
    let slabs = nz.div_ceil(SLAB);
    let slab = |t: usize| (t * SLAB, ((t + 1) * SLAB).min(nz));
    let bins = Bins::from_fn([1, 1, slabs], splats.len(), |at| {
        let s = &splats[at].1;
        let slabs = TileBox {
            lo: [0, 0, s.lo[2] / SLAB],
            hi: [1, 1, (s.hi[2] - 1) / SLAB + 1],
        };
        Some((slabs, at as u32))
    });
    let buffers: Vec<Vec<f32>> = (0..slabs)
        .into_par_iter()
        .map(|t| {
            let (z0, z1) = slab(t);
            let pass = Pass {
                centres: &centres,
                pad: Slices::new(grid, z0, z1),
                cut2,
            };
            let mut buf = pass.pad.rows.zeros(m);
            // The list is in index order, so each voxel still sums its Gaussians in that order.
            for &at in bins.of(t) {
                let &(gi, ref s) = &splats[at as usize];
                let dens = &g.densities[m * gi..m * gi + m];
                let zs = s.lo[2].max(z0)..s.hi[2].min(z1);
                voxel_forward(s, pass, zs, dens, &mut buf);
            }
            buf
        })
        .collect();
    for (t, buf) in buffers.iter().enumerate() {
        let (z0, z1) = slab(t);
        Slices::new(grid, z0, z1)
            .rows
            .unpad_into(buf, &mut out, nz * ny, z0 * ny);
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
        means: zeros(3 * k),
        scales: zeros(3 * k),
        rotations: zeros(4 * k),
        densities: zeros(m * k),
    };
    if k == 0 || vol == 0 || m == 0 {
        return total;
    }
    assert_eq!(
        grad.len(),
        m * vol,
        "the upstream gradient is [M, nz, ny, nx]"
    );
    let cut2 = (opts.cutoff * opts.cutoff) as f32;
    let splats = prepare(g, grid, opts.cutoff);
    let centres = Centres::new(grid);
    let pass = Pass {
        centres: &centres,
        pad: Slices::new(grid, 0, grid.dims[2]),
        cut2,
    };
    let padded = pass.pad.rows.pad(grad);
    let upstream = UpstreamGrad {
        values: &padded,
        finite: grad.par_iter().all(|v| v.is_finite()),
    };
    // Per Gaussian near the grid: [S_0..S_{M-1}, Σ wG d (3), Σ wG d dᵀ packed (6)],
    // w = Σ_c ρ_c g_c, and its chain to the parameters; then added to its rows.
    let stride = m + 9;
    let mut sums = vec![0.0f64; splats.len() * stride];
    let mut geos = vec![GeomGrad::default(); splats.len()];
    sums.par_chunks_mut(stride)
        .zip(geos.par_iter_mut())
        .zip(splats.par_iter())
        .with_min_len(4)
        .for_each_init(
            || vec![[0.0f32; LANES]; m],
            |lanes, ((sum, geo), (i, s))| {
                let dens = &g.densities[m * i..m * i + m];
                for x0 in s.blocks() {
                    voxel_backward_sums(s, pass, x0, upstream, dens, lanes, sum);
                }
                let sum_d = [sum[m], sum[m + 1], sum[m + 2]];
                let p = &sum[m + 3..m + 9];
                let sum_dd = [[p[0], p[1], p[2]], [p[1], p[3], p[4]], [p[2], p[4], p[5]]];
                *geo = voxel_backward(&g.geom(*i), sum_d, &sum_dd);
            },
        );
    let VoxelizeGrads {
        means,
        scales,
        rotations,
        densities,
    } = &mut total;
    for (((i, _), geo), sum) in splats.iter().zip(&geos).zip(sums.chunks_exact(stride)) {
        grad_row(means, scales, rotations, densities, m, *i).add(0, geo, 1.0, &sum[..m]);
    }
    total
}
