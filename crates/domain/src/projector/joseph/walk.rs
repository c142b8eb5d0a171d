//! Rays through the voxel grid in index space: the general walk along a ray's dominant axis
//! (bilinear samples in the other two, zero outside the grid), the column geometry the sheets
//! share, memory layouts of the volume, and the per-worker accumulators of the adjoint.

use super::*;

/// What a ray visits: either four bilinear neighbours in one plane, all inside the grid, or single
/// voxels near the border.
pub(super) trait Visit {
    /// Interior sample: corners `base`, `base + o1`, `base + o2`, `base + o1 + o2` with fractional
    /// positions `f1`, `f2` along the two in-plane axes.
    fn quad(&mut self, base: usize, o1: usize, o2: usize, f1: f32, f2: f32);
    /// One voxel with weight `w` (border samples).
    fn one(&mut self, idx: usize, w: f32);
}

/// Inclusive voxel-index box `([x, y, z] lo, [x, y, z] hi)`.
pub(super) type Support = ([usize; 3], [usize; 3]);

/// Bounding box of the non-zero voxels of a `[z][y][x]` volume with `dims = [nx, ny, nz]`, or
/// `None` when every voxel is zero (empty-space skipping for the forward projector; exact, since
/// skipped samples only touch zero voxels).
pub(super) fn support(vol: &[f32], dims: [usize; 3]) -> Option<Support> {
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

/// Strides of x, y and z in a volume buffer.
#[derive(Clone, Copy, Debug)]
pub(super) struct Layout {
    pub(super) stride: [usize; 3],
}

impl Layout {
    /// The array convention `[z][y][x]`.
    pub(super) fn zyx([nx, ny, _]: [usize; 3]) -> Layout {
        Layout {
            stride: [1, nx, nx * ny],
        }
    }

    /// z fastest, `[y][x][z]`: the sheets' z-lines are contiguous.
    pub(super) fn yxz([nx, _, nz]: [usize; 3]) -> Layout {
        Layout {
            stride: [nz, nx * nz, 1],
        }
    }
}

/// Copy a `[z][y][x]` volume to `[y][x][z]`.
pub(super) fn to_yxz(vol: &[f32], [nx, ny, nz]: [usize; 3]) -> Vec<f32> {
    let mut out = vec![0.0f32; vol.len()];
    out.par_chunks_mut(nx * nz)
        .enumerate()
        .for_each(|(y, slab)| {
            for z in 0..nz {
                let line = &vol[(z * ny + y) * nx..(z * ny + y + 1) * nx];
                for (x, &v) in line.iter().enumerate() {
                    slab[x * nz + z] = v;
                }
            }
        });
    out
}

/// Copy a `[y][x][z]` volume back to `[z][y][x]` (blocks of z-slices per task, so that each z-line
/// is read once).
pub(crate) fn from_yxz(vt: &[f32], [nx, ny, nz]: [usize; 3]) -> Vec<f32> {
    const ZB: usize = 16;
    let slice = nx * ny;
    let mut out = vec![0.0f32; vt.len()];
    out.par_chunks_mut(ZB * slice)
        .enumerate()
        .for_each(|(b, chunk)| {
            let z0 = b * ZB;
            let zb = chunk.len() / slice;
            for xy in 0..slice {
                let line = &vt[xy * nz + z0..xy * nz + z0 + zb];
                for (dz, &v) in line.iter().enumerate() {
                    chunk[dz * slice + xy] = v;
                }
            }
        });
    out
}

/// Swap the last two axes of `[n][a][b]` data (`a·b` per slab), in parallel over slabs.
pub(super) fn swap_last(data: &[f32], a: usize, b: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; data.len()];
    if a * b == 0 {
        return out;
    }
    out.par_chunks_mut(a * b)
        .zip(data.par_chunks(a * b))
        .for_each(|(dst, src)| {
            for (i, line) in src.chunks(b).enumerate() {
                for (j, &v) in line.iter().enumerate() {
                    dst[j * a + i] = v;
                }
            }
        });
    out
}

/// A ray in continuous voxel-index space: `a + s·g` for `s ∈ [0, 1]`, from the source (cone) or
/// the start plane (parallel) to the detector pixel; `len` is its length in mm.
pub(super) struct IndexRay {
    pub(super) a: [f64; 3],
    pub(super) g: [f64; 3],
    pub(super) len: f64,
}

/// The rays of one detector column: origin, index-space displacement and world displacement are
/// affine in the row (the pixel centre moves linearly along the column), so row `r`'s ray is
/// row 0's plus `r` times the per-row change.
pub(super) struct ColumnRays {
    pub(super) a: [[f64; 3]; 2],
    pub(super) g: [[f64; 3]; 2],
    pub(super) d: [[f64; 3]; 2],
}

impl ColumnRays {
    pub(super) fn ray(&self, row: usize) -> IndexRay {
        let r = row as f64;
        let at = |v: &[[f64; 3]; 2]| [0, 1, 2].map(|i| v[0][i] + r * v[1][i]);
        let d = at(&self.d);
        IndexRay {
            a: at(&self.a),
            g: at(&self.g),
            len: (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(),
        }
    }
}

/// Dominant axis of an index-space direction (ties go to the later axis).
pub(super) fn dominant(g: &[f64; 3]) -> usize {
    (0..3)
        .max_by(|&p, &q| g[p].abs().total_cmp(&g[q].abs()))
        .expect("three axes")
}

/// Per-ray stepping data in index space, precomputed once per ray (the general walk).
pub(super) struct RayWalk {
    /// Dominant axis (0 = x, 1 = y, 2 = z) and the two in-plane axes.
    pub(super) k: usize,
    pub(super) j: [usize; 2],
    /// First and last plane index (inclusive) along `k`; empty when `lo > hi`.
    pub(super) lo: i64,
    pub(super) hi: i64,
    /// In-plane continuous index at plane `lo` and its increment per plane.
    pub(super) p0: [f64; 2],
    pub(super) dp: [f64; 2],
    /// Ray length per plane, mm.
    pub(super) step: f32,
}

/// Clip `s ∈ [t0, t1]` so that `a[axis] + s·g[axis]` lies in `[lo, hi]`; a ray parallel to the
/// slab must lie strictly inside it. Returns the new interval (empty when `t1 ≤ t0`).
pub(super) fn clip(a: f64, g: f64, lo: f64, hi: f64, (t0, t1): (f64, f64)) -> (f64, f64) {
    if g == 0.0 {
        if a <= lo || a >= hi {
            return (t0, -1.0);
        }
        (t0, t1)
    } else {
        let (ta, tb) = ((lo - a) / g, (hi - a) / g);
        (t0.max(ta.min(tb)), t1.min(ta.max(tb)))
    }
}

/// Walk of `ray` along axis `k`, or `None` when no sample footprint touches `support` (the
/// inclusive voxel box outside which the operand is zero; the whole grid for the adjoint).
pub(super) fn walk(ray: &IndexRay, k: usize, support: &Support) -> Option<RayWalk> {
    let (a, g) = (&ray.a, &ray.g);
    if g[k] == 0.0 {
        return None;
    }
    let j = match k {
        0 => [1, 2],
        1 => [0, 2],
        _ => [0, 1],
    };
    // Parameter interval where the sample footprint touches the support: dominant axis within
    // [lo − ½, hi + ½] (voxel slabs), in-plane axes within (lo − 1, hi + 1).
    let (blo, bhi) = (support.0.map(|x| x as f64), support.1.map(|x| x as f64));
    let mut t = (0.0, 1.0);
    t = clip(a[k], g[k], blo[k] - 0.5, bhi[k] + 0.5, t);
    for &jj in &j {
        t = clip(a[jj], g[jj], blo[jj] - 1.0, bhi[jj] + 1.0, t);
    }
    if t.1 <= t.0 {
        return None;
    }
    // Planes i (index along k) whose sample point lies in [t0, t1].
    let (ka, kb) = (a[k] + t.0 * g[k], a[k] + t.1 * g[k]);
    let lo = ka.min(kb).ceil().max(blo[k]) as i64;
    let hi = (ka.max(kb).floor() as i64).min(bhi[k] as i64);
    if lo > hi {
        return None;
    }
    let dp = [g[j[0]] / g[k], g[j[1]] / g[k]];
    let dt = lo as f64 - a[k];
    Some(RayWalk {
        k,
        j,
        lo,
        hi,
        p0: [a[j[0]] + dt * dp[0], a[j[1]] + dt * dp[1]],
        dp,
        step: (ray.len / g[k].abs()) as f32,
    })
}

/// The horizontal walk shared by the rays of one detector column (see the module docs): planes
/// `lo..=hi` along the horizontal axis `k`, position `p0 + m·dp` (m = plane − lo) along the other
/// horizontal axis `j`.
pub(super) struct ColumnWalk {
    pub(super) k: usize,
    pub(super) j: usize,
    pub(super) lo: i64,
    pub(super) hi: i64,
    pub(super) p0: f32,
    pub(super) dp: f32,
}

impl ColumnWalk {
    /// Number of planes.
    pub(super) fn planes(&self) -> usize {
        (self.hi - self.lo + 1).max(0) as usize
    }

    /// Index along `j` and weight of the two horizontal neighbours at plane offset `m`.
    #[inline(always)]
    pub(super) fn corners(&self, m: usize) -> [(i32, f32); 2] {
        let p = self.p0 + m as f32 * self.dp;
        let q = floorish(p);
        let f = p - q as f32;
        [(q, 1.0 - f), (q + 1, f)]
    }

    /// `ray` (a row of this column) as a walk over the sheet, whose z rows cover
    /// `[zlo − 1, zhi + 1]`; `None` when no sample falls there.
    pub(super) fn sheet_ray(&self, ray: &IndexRay, zlo: usize, zhi: usize) -> Option<SheetRay> {
        let (a, g) = (&ray.a, &ray.g);
        let dz = g[2] / g[self.k];
        let z0 = a[2] + (self.lo as f64 - a[self.k]) * dz;
        let last = (self.hi - self.lo) as f64;
        let (zmin, zmax) = (zlo as f64 - 1.0, zhi as f64 + 1.0);
        let (m0, m1) = if dz == 0.0 {
            if !(z0 >= zmin && z0 <= zmax) {
                return None;
            }
            (0.0, last)
        } else {
            let (ma, mb) = ((zmin - z0) / dz, (zmax - z0) / dz);
            (ma.min(mb).ceil().max(0.0), ma.max(mb).floor().min(last))
        };
        if m0 > m1 {
            return None;
        }
        Some(SheetRay {
            m0: m0 as usize,
            m1: m1 as usize,
            z0: z0 as f32,
            dz: dz as f32,
            step: (ray.len / g[self.k].abs()) as f32,
        })
    }
}

/// Rounding constant of [`floorish`]: 1.5·2²³.
pub(crate) const MAGIC: f32 = 12_582_912.0;

/// `q` with `q ≤ x ≤ q + 1` for |x| < 2²², without a rounding instruction or a saturating cast
/// (both are slow on baseline x86-64 and block vectorisation): adding 1.5·2²³ rounds `x − ½` to
/// the nearest integer, which lands in the low mantissa bits. At exact integers the tie may round
/// down, giving `x − q = 1`, which bilinear interpolation handles like 0 at `q + 1`.
#[inline(always)]
pub(crate) fn floorish(x: f32) -> i32 {
    ((x - 0.5) + MAGIC).to_bits() as i32 - MAGIC.to_bits() as i32
}

/// Visit every sample of `walk` on a grid of `dims = [nx, ny, nz]` stored with `layout`.
#[inline(always)]
pub(super) fn run<V: Visit>(walk: &RayWalk, dims: [usize; 3], layout: Layout, v: &mut V) {
    /// Samples per batch: positions of a batch are computed first (a loop the compiler
    /// vectorises), then the batch is visited.
    const BATCH: usize = 64;
    let stride = layout.stride;
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

pub(super) struct Gather<'a> {
    pub(super) vol: &'a [f32],
    pub(super) sum: f32,
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

pub(super) struct Scatter<'a> {
    pub(super) acc: &'a mut [f32],
    pub(super) val: f32,
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
pub(super) fn reduce(mut parts: Vec<Vec<f32>>, n: usize) -> Vec<f32> {
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
