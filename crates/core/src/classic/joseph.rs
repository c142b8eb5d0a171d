//! Ray-driven Joseph forward projector and its exact adjoint.
//!
//! One ray per detector-pixel centre ([`Camera::pixel_ray`]): from the source (cone) or the start
//! plane (parallel) to the detector. The ray is stepped along its *dominant* volume axis (the axis
//! whose voxel index changes fastest along the ray); at every voxel-centre plane of that axis the
//! volume is sampled bilinearly in the other two axes (zero outside the grid) and the sample is
//! weighted by the ray length per plane, `Δt = d_k / |cos|` (mm). A projection is therefore
//! `Σ_i Δt · bilinear(slice_i)`, a line integral in μ·mm units.
//!
//! The adjoint scatters exactly the same weights ([`Joseph::adjoint`]), so
//! `⟨A x, y⟩ = ⟨x, Aᵀ y⟩` up to float rounding, which CGLS needs. It is parallel over rays with one
//! accumulator volume per worker (no atomics, no races), reduced at the end.
//!
//! Arrays: volumes `[z][y][x]`, projections `[view][row][col]` (see `docs/geometry.md`).

use crate::geometry::{Camera, Geometry};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

/// Ray-driven trilinear (Joseph) projector bound to one geometry.
#[derive(Clone, Debug)]
pub struct Joseph {
    geometry: Geometry,
    cameras: Vec<Camera>,
}

/// What a ray visits: either four bilinear neighbours in one plane, all inside the grid, or single
/// voxels near the border.
trait Visit {
    /// Interior sample: corners `base`, `base + o1`, `base + o2`, `base + o1 + o2` with fractional
    /// positions `f1`, `f2` along the two in-plane axes.
    fn quad(&mut self, base: usize, o1: usize, o2: usize, f1: f32, f2: f32);
    /// One voxel with weight `w` (border samples).
    fn one(&mut self, idx: usize, w: f32);
}

/// Inclusive voxel-index box `([x, y, z] lo, [x, y, z] hi)`.
type Support = ([usize; 3], [usize; 3]);

/// Bounding box of the non-zero voxels of a `[z][y][x]` volume with `dims = [nx, ny, nz]`, or
/// `None` when every voxel is zero (empty-space skipping for the forward projector; exact, since
/// skipped samples only touch zero voxels).
fn support(vol: &[f32], dims: [usize; 3]) -> Option<Support> {
    let [nx, ny, _] = dims;
    vol.par_chunks(nx * ny)
        .enumerate()
        .filter_map(|(z, slice)| {
            let mut b: Option<Support> = None;
            for (y, line) in slice.chunks(nx).enumerate() {
                let first = line.iter().position(|&v| v != 0.0);
                if let Some(x0) = first {
                    let x1 = line.iter().rposition(|&v| v != 0.0).unwrap_or(x0);
                    b = Some(match b {
                        None => ([x0, y, z], [x1, y, z]),
                        Some((lo, hi)) => ([lo[0].min(x0), lo[1], z], [hi[0].max(x1), y, z]),
                    });
                }
            }
            b
        })
        .reduce_with(|a, b| {
            (
                [a.0[0].min(b.0[0]), a.0[1].min(b.0[1]), a.0[2].min(b.0[2])],
                [a.1[0].max(b.1[0]), a.1[1].max(b.1[1]), a.1[2].max(b.1[2])],
            )
        })
}

/// Per-ray stepping data in index space, precomputed once per ray.
struct RayWalk {
    /// Dominant axis (0 = x, 1 = y, 2 = z) and the two in-plane axes.
    k: usize,
    j: [usize; 2],
    /// First and last plane index (inclusive) along `k`; empty when `lo > hi`.
    lo: i64,
    hi: i64,
    /// In-plane continuous index at plane `lo` and its increment per plane.
    p0: [f64; 2],
    dp: [f64; 2],
    /// Ray length per plane, mm.
    step: f32,
}

impl Joseph {
    /// Bind a projector to `geometry` (validated).
    pub fn new(geometry: &Geometry) -> Result<Self> {
        geometry.validate()?;
        Ok(Joseph {
            cameras: geometry.cameras(),
            geometry: geometry.clone(),
        })
    }

    /// The geometry this projector was built for.
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.cameras.len()
    }

    /// Shape `[views, rows, cols]` of the projections of `n_views` views.
    pub fn projection_shape(&self, n_views: usize) -> [usize; 3] {
        let d = &self.geometry.detector;
        [n_views, d.rows, d.cols]
    }

    /// Project `volume` (`[z][y][x]`, μ in mm⁻¹) into all views: `[view][row][col]` line integrals.
    pub fn forward(&self, volume: ArrayView3<f32>) -> Result<Array3<f32>> {
        let all: Vec<usize> = (0..self.views()).collect();
        self.forward_views(volume, &all)
    }

    /// Project `volume` into the listed views only; output slab `k` is view `views[k]`.
    pub fn forward_views(&self, volume: ArrayView3<f32>, views: &[usize]) -> Result<Array3<f32>> {
        self.check_volume(volume, "volume")?;
        self.check_views(views)?;
        let g = &self.geometry.volume;
        let vol = volume.as_standard_layout();
        let vol = vol.as_slice().expect("standard layout");
        let dims = [g.nx, g.ny, g.nz];
        let mut out = Array3::<f32>::zeros(self.projection_shape(views.len()));
        let Some(support) = support(vol, dims) else {
            return Ok(out); // an all-zero volume projects to zero
        };
        let (rows, cols) = (self.geometry.detector.rows, self.geometry.detector.cols);
        out.as_slice_mut()
            .expect("fresh array")
            .par_chunks_mut(cols)
            .enumerate()
            .for_each(|(line, out_row)| {
                let (k, row) = (line / rows, line % rows);
                let cam = &self.cameras[views[k]];
                for (col, o) in out_row.iter_mut().enumerate() {
                    let mut acc = Gather { vol, sum: 0.0 };
                    if let Some(walk) = self.walk(cam, col, row, &support) {
                        run(&walk, dims, &mut acc);
                        *o = acc.sum * walk.step;
                    }
                }
            });
        Ok(out)
    }

    /// Exact adjoint of [`Joseph::forward`]: `Aᵀ y` for projections `[view][row][col]` of all views.
    pub fn adjoint(&self, projections: ArrayView3<f32>) -> Result<Array3<f32>> {
        let all: Vec<usize> = (0..self.views()).collect();
        self.adjoint_views(projections, &all)
    }

    /// Exact adjoint of [`Joseph::forward_views`] for the same `views`.
    pub fn adjoint_views(
        &self,
        projections: ArrayView3<f32>,
        views: &[usize],
    ) -> Result<Array3<f32>> {
        self.check_views(views)?;
        let want = self.projection_shape(views.len());
        crate::error::ensure_shape(
            "projections",
            projections.shape(),
            &want,
            "[views, rows, cols]",
        )?;
        let g = &self.geometry.volume;
        let dims = [g.nx, g.ny, g.nz];
        let n = g.len();
        let proj = projections.as_standard_layout();
        let proj = proj.as_slice().expect("standard layout");
        let (rows, cols) = (self.geometry.detector.rows, self.geometry.detector.cols);
        let lines = views.len() * rows;
        let full: Support = ([0; 3], [g.nx - 1, g.ny - 1, g.nz - 1]);
        // One accumulator per worker over a contiguous run of detector lines.
        let workers = rayon::current_num_threads().clamp(1, lines.max(1));
        let per = lines.div_ceil(workers);
        let partial: Vec<Vec<f32>> = (0..workers)
            .into_par_iter()
            .map(|w| {
                let mut acc = vec![0.0f32; n];
                for line in (w * per)..((w + 1) * per).min(lines) {
                    let (k, row) = (line / rows, line % rows);
                    let cam = &self.cameras[views[k]];
                    let vals = &proj[line * cols..(line + 1) * cols];
                    for (col, &val) in vals.iter().enumerate() {
                        if val == 0.0 {
                            continue;
                        }
                        if let Some(walk) = self.walk(cam, col, row, &full) {
                            let mut s = Scatter {
                                acc: &mut acc,
                                val: val * walk.step,
                            };
                            run(&walk, dims, &mut s);
                        }
                    }
                }
                acc
            })
            .collect();
        Ok(Array3::from_shape_vec(g.shape_zyx(), reduce(partial, n)).expect("grid shape"))
    }

    /// Ray length inside the volume per pixel, `A·1`: the row sums of the system matrix.
    pub fn ray_lengths(&self, views: &[usize]) -> Result<Array3<f32>> {
        let ones = Array3::<f32>::ones(self.geometry.volume.shape_zyx());
        self.forward_views(ones.view(), views)
    }

    fn check_volume(&self, volume: ArrayView3<f32>, field: &str) -> Result<()> {
        let want = self.geometry.volume.shape_zyx();
        if volume.shape() != want {
            return Err(Error::invalid(
                field,
                format!(
                    "shape {:?} does not match the grid [nz, ny, nx] = {want:?}",
                    volume.shape()
                ),
            ));
        }
        Ok(())
    }

    fn check_views(&self, views: &[usize]) -> Result<()> {
        if views.is_empty() {
            return Err(Error::invalid("views", "the view list is empty"));
        }
        if let Some(v) = views.iter().find(|&&v| v >= self.views()) {
            return Err(Error::invalid(
                "views",
                format!(
                    "view {v} does not exist (the geometry has {} views)",
                    self.views()
                ),
            ));
        }
        Ok(())
    }

    /// Set up the walk of the ray through pixel (col, row), or `None` when it misses the grid.
    /// `support` = inclusive voxel-index box `(lo, hi)` outside which the operand is zero (the
    /// whole grid for the adjoint): samples whose footprint lies outside it are skipped.
    fn walk(&self, cam: &Camera, col: usize, row: usize, support: &Support) -> Option<RayWalk> {
        let g = &self.geometry.volume;
        let ray = cam.pixel_ray(col as f64, row as f64);
        let a = g.world_to_index(ray.origin);
        let vs = g.voxel_size();
        let gd = [
            ray.direction[0] / vs[0],
            ray.direction[1] / vs[1],
            ray.direction[2] / vs[2],
        ];
        let k = (0..3)
            .max_by(|&p, &q| gd[p].abs().total_cmp(&gd[q].abs()))
            .expect("three axes");
        if gd[k] == 0.0 {
            return None;
        }
        let j = match k {
            0 => [1, 2],
            1 => [0, 2],
            _ => [0, 1],
        };
        // Parameter interval (mm along the ray) where the sample footprint touches the grid:
        // dominant axis within [−½, n−½] (voxel slabs), in-plane axes within (−1, n).
        let mut t0 = 0.0f64;
        let mut t1 = ray.length;
        let mut clip = |axis: usize, lo: f64, hi: f64| {
            if gd[axis] == 0.0 {
                if a[axis] <= lo || a[axis] >= hi {
                    t1 = -1.0;
                }
            } else {
                let (ta, tb) = ((lo - a[axis]) / gd[axis], (hi - a[axis]) / gd[axis]);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        };
        let (blo, bhi) = (support.0.map(|x| x as f64), support.1.map(|x| x as f64));
        clip(k, blo[k] - 0.5, bhi[k] + 0.5);
        clip(j[0], blo[j[0]] - 1.0, bhi[j[0]] + 1.0);
        clip(j[1], blo[j[1]] - 1.0, bhi[j[1]] + 1.0);
        if t1 <= t0 {
            return None;
        }
        // Planes i (index along k) whose sample point lies in [t0, t1].
        let (ka, kb) = (a[k] + t0 * gd[k], a[k] + t1 * gd[k]);
        let lo = ka.min(kb).ceil().max(blo[k]) as i64;
        let hi = (ka.max(kb).floor() as i64).min(bhi[k] as i64);
        if lo > hi {
            return None;
        }
        let dp = [gd[j[0]] / gd[k], gd[j[1]] / gd[k]];
        let dt = lo as f64 - a[k];
        Some(RayWalk {
            k,
            j,
            lo,
            hi,
            p0: [a[j[0]] + dt * dp[0], a[j[1]] + dt * dp[1]],
            dp,
            step: (1.0 / gd[k].abs()) as f32,
        })
    }
}

/// `q` with `q ≤ x ≤ q + 1` for |x| < 2²², without a rounding instruction or a saturating cast
/// (both are slow on baseline x86-64 and block vectorisation): adding 1.5·2²³ rounds `x − ½` to
/// the nearest integer, which lands in the low mantissa bits. At exact integers the tie may round
/// down, giving `x − q = 1`, which bilinear interpolation handles like 0 at `q + 1`.
#[inline(always)]
pub(crate) fn floorish(x: f32) -> i32 {
    const MAGIC: f32 = 12_582_912.0;
    ((x - 0.5) + MAGIC).to_bits() as i32 - MAGIC.to_bits() as i32
}

/// Visit every sample of `walk` on a grid of `dims = [nx, ny, nz]`.
#[inline(always)]
fn run<V: Visit>(walk: &RayWalk, dims: [usize; 3], v: &mut V) {
    /// Samples per batch: positions of a batch are computed first (a loop the compiler
    /// vectorises), then the batch is visited.
    const BATCH: usize = 64;
    let stride = [1usize, dims[0], dims[0] * dims[1]];
    let (sk, s1, s2) = (stride[walk.k], stride[walk.j[0]], stride[walk.j[1]]);
    let (n1, n2) = (dims[walk.j[0]] as i32, dims[walk.j[1]] as i32);
    let (p01, p02) = (walk.p0[0] as f32, walk.p0[1] as f32);
    let (dp1, dp2) = (walk.dp[0] as f32, walk.dp[1] as f32);
    let len = (walk.hi - walk.lo + 1) as usize;
    let (s1i, s2i) = (s1 as i32, s2 as i32);
    // Unsigned compares: q ∈ [0, n − 2] ⇔ (q as u32) < n − 1 (negative q wraps to huge).
    let (lim1, lim2) = ((n1 - 1) as u32, (n2 - 1) as u32);
    let mut q1 = [0i32; BATCH];
    let mut q2 = [0i32; BATCH];
    let mut f1 = [0f32; BATCH];
    let mut f2 = [0f32; BATCH];
    let mut off = [0i32; BATCH];
    let mut inside = [false; BATCH];
    let mut start = 0;
    while start < len {
        let cnt = BATCH.min(len - start);
        for t in 0..cnt {
            let m = (start + t) as f32;
            let (p1, p2) = (p01 + m * dp1, p02 + m * dp2);
            let (a, b) = (floorish(p1), floorish(p2));
            q1[t] = a;
            q2[t] = b;
            f1[t] = p1 - a as f32;
            f2[t] = p2 - b as f32;
            off[t] = a.wrapping_mul(s1i).wrapping_add(b.wrapping_mul(s2i));
            inside[t] = ((a as u32) < lim1) & ((b as u32) < lim2);
        }
        let plane0 = (walk.lo as usize + start) * sk;
        for t in 0..cnt {
            let plane = plane0 + t * sk;
            if inside[t] {
                v.quad(plane + off[t] as usize, s1, s2, f1[t], f2[t]);
            } else {
                let (i1, i2, g1, g2) = (q1[t], q2[t], f1[t], f2[t]);
                for (d1, w1) in [(0i32, 1.0 - g1), (1, g1)] {
                    for (d2, w2) in [(0i32, 1.0 - g2), (1, g2)] {
                        let (c1, c2) = (i1 + d1, i2 + d2);
                        if c1 >= 0 && c1 < n1 && c2 >= 0 && c2 < n2 {
                            v.one(plane + c1 as usize * s1 + c2 as usize * s2, w1 * w2);
                        }
                    }
                }
            }
        }
        start += cnt;
    }
}

struct Gather<'a> {
    vol: &'a [f32],
    sum: f32,
}

impl Visit for Gather<'_> {
    #[inline(always)]
    fn quad(&mut self, base: usize, o1: usize, o2: usize, f1: f32, f2: f32) {
        // One bounds check for the whole 2×2 cell.
        let v = &self.vol[base..=base + o1 + o2];
        let a = v[0] + f1 * (v[o1] - v[0]);
        let b = v[o2] + f1 * (v[o1 + o2] - v[o2]);
        self.sum += a + f2 * (b - a);
    }
    #[inline(always)]
    fn one(&mut self, idx: usize, w: f32) {
        self.sum += w * self.vol[idx];
    }
}

struct Scatter<'a> {
    acc: &'a mut [f32],
    val: f32,
}

impl Visit for Scatter<'_> {
    #[inline(always)]
    fn quad(&mut self, base: usize, o1: usize, o2: usize, f1: f32, f2: f32) {
        let (g1, g2) = (1.0 - f1, 1.0 - f2);
        let a = &mut self.acc[base..=base + o1 + o2];
        a[0] += self.val * g1 * g2;
        a[o1] += self.val * f1 * g2;
        a[o2] += self.val * g1 * f2;
        a[o1 + o2] += self.val * f1 * f2;
    }
    #[inline(always)]
    fn one(&mut self, idx: usize, w: f32) {
        self.acc[idx] += self.val * w;
    }
}

/// Sum per-worker accumulators into one buffer (parallel over voxel chunks).
pub(crate) fn reduce(mut parts: Vec<Vec<f32>>, n: usize) -> Vec<f32> {
    let Some(mut first) = parts.pop() else {
        return vec![0.0; n];
    };
    const CHUNK: usize = 1 << 15;
    first
        .par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, dst)| {
            let len = dst.len();
            for p in &parts {
                for (d, s) in dst.iter_mut().zip(&p[c * CHUNK..c * CHUNK + len]) {
                    *d += s;
                }
            }
        });
    first
}

/// Inner product in f64 of two equally shaped arrays.
pub fn dot(a: ArrayView3<f32>, b: ArrayView3<f32>) -> f64 {
    a.iter()
        .zip(b.iter())
        .map(|(&p, &q)| p as f64 * q as f64)
        .sum()
}

/// `a[i] = f(a[i], b[i])` in parallel, for equally shaped standard-layout arrays.
pub(crate) fn par_zip(a: &mut Array3<f32>, b: &Array3<f32>, f: impl Fn(f32, f32) -> f32 + Sync) {
    let b = b.as_slice().expect("standard layout");
    a.as_slice_mut()
        .expect("standard layout")
        .par_iter_mut()
        .zip(b.par_iter())
        .for_each(|(x, &y)| *x = f(*x, y));
}

#[cfg(test)]
#[path = "joseph_tests.rs"]
mod tests;
