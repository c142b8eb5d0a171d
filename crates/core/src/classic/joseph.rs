//! Ray-driven Joseph forward projector and its exact adjoint.
//!
//! One ray per detector-pixel centre (as [`Camera::pixel_ray`]): from the source (cone) or the
//! start plane (parallel) to the detector. The ray is stepped along its *dominant* volume axis (the
//! axis whose voxel index changes fastest along the ray); at every voxel-centre plane of that axis
//! the volume is sampled bilinearly in the other two axes (zero outside the grid) and the sample is
//! weighted by the ray length per plane, `Δt = d_k / |cos|` (mm). A projection is therefore
//! `Σ_i Δt · bilinear(slice_i)`, a line integral in μ·mm units.
//!
//! **Column sheets.** The rotation axis is z and detector columns are parallel to it
//! (`docs/geometry.md`), so the rays through one detector column of one view lie in one vertical
//! plane and share their x/y path. For a ray whose dominant axis is x or y (every ray unless the
//! cone angle exceeds 45°) the plane positions along the dominant axis and along the other
//! horizontal axis are the same for every row of the column; only z differs. Bilinear sampling is
//! separable, so the horizontal interpolation is done once per column: the *sheet*
//! `S[i][z] = (1 − f_i)·V(i, q_i, z) + f_i·V(i, q_i + 1, z)` at plane `i`, for every z. Each ray of
//! the column then costs one linear interpolation in z per plane, which AVX2 (detected at run
//! time) gathers eight planes at a time. Rays whose dominant axis is z take the general per-ray
//! walk. When several views are projected, the forward pass first copies the volume to z-fastest
//! order so that sheets are built from contiguous z-lines.
//!
//! The adjoint is the transpose of the same steps (rays scatter into the sheet, the sheet into the
//! volume, identical sample positions and weights), so `⟨A x, y⟩ = ⟨x, Aᵀ y⟩` up to float rounding,
//! which CGLS needs. It is parallel over detector columns with one accumulator volume per worker
//! (no atomics, no races), reduced at the end.
//!
//! Arrays: volumes `[z][y][x]`, projections `[view][row][col]` (see `docs/geometry.md`).

use crate::geometry::{Camera, Geometry, Projection};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

/// Ray-driven trilinear (Joseph) projector bound to one geometry.
#[derive(Clone, Debug)]
pub struct Joseph {
    geometry: Geometry,
    cameras: Vec<Camera>,
    /// Use the AVX2+FMA sheet sampler (the CPU has it; tests switch it off to cover both paths).
    simd: bool,
    /// Trace rays on column sheets where possible; when false every ray takes the general walk
    /// (the reference the tests compare the sheets against).
    sheets: bool,
}

/// Projecting at least this many views copies the volume to z-fastest order first (the copy costs
/// about as much as projecting a view or two; single-view calls, as in SART, skip it).
const TRANSPOSE_MIN_VIEWS: usize = 4;

/// Lanes of the AVX2 sheet sampler; sheets carry this many planes of slack minus one.
const LANES: usize = 8;

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

/// Strides of x, y and z in a volume buffer.
#[derive(Clone, Copy, Debug)]
struct Layout {
    stride: [usize; 3],
}

impl Layout {
    /// The array convention `[z][y][x]`.
    fn zyx([nx, ny, _]: [usize; 3]) -> Layout {
        Layout {
            stride: [1, nx, nx * ny],
        }
    }

    /// z fastest, `[y][x][z]`: the sheets' z-lines are contiguous.
    fn yxz([nx, _, nz]: [usize; 3]) -> Layout {
        Layout {
            stride: [nz, nx * nz, 1],
        }
    }
}

/// Copy a `[z][y][x]` volume to `[y][x][z]`.
fn to_yxz(vol: &[f32], [nx, ny, nz]: [usize; 3]) -> Vec<f32> {
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
fn swap_last(data: &[f32], a: usize, b: usize) -> Vec<f32> {
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
struct IndexRay {
    a: [f64; 3],
    g: [f64; 3],
    len: f64,
}

/// The rays of one detector column: origin, index-space displacement and world displacement are
/// affine in the row (the pixel centre moves linearly along the column), so row `r`'s ray is
/// row 0's plus `r` times the per-row change.
struct ColumnRays {
    a: [[f64; 3]; 2],
    g: [[f64; 3]; 2],
    d: [[f64; 3]; 2],
}

impl ColumnRays {
    fn ray(&self, row: usize) -> IndexRay {
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
fn dominant(g: &[f64; 3]) -> usize {
    (0..3)
        .max_by(|&p, &q| g[p].abs().total_cmp(&g[q].abs()))
        .expect("three axes")
}

/// Per-ray stepping data in index space, precomputed once per ray (the general walk).
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

/// Clip `s ∈ [t0, t1]` so that `a[axis] + s·g[axis]` lies in `[lo, hi]`; a ray parallel to the
/// slab must lie strictly inside it. Returns the new interval (empty when `t1 ≤ t0`).
fn clip(a: f64, g: f64, lo: f64, hi: f64, (t0, t1): (f64, f64)) -> (f64, f64) {
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
fn walk(ray: &IndexRay, k: usize, support: &Support) -> Option<RayWalk> {
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
struct ColumnWalk {
    k: usize,
    j: usize,
    lo: i64,
    hi: i64,
    p0: f32,
    dp: f32,
}

impl ColumnWalk {
    /// Number of planes.
    fn planes(&self) -> usize {
        (self.hi - self.lo + 1).max(0) as usize
    }

    /// Index along `j` and weight of the two horizontal neighbours at plane offset `m`.
    #[inline(always)]
    fn corners(&self, m: usize) -> [(i32, f32); 2] {
        let p = self.p0 + m as f32 * self.dp;
        let q = floorish(p);
        let f = p - q as f32;
        [(q, 1.0 - f), (q + 1, f)]
    }

    /// `ray` (a row of this column) as a walk over the sheet, whose z rows cover
    /// `[zlo − 1, zhi + 1]`; `None` when no sample falls there.
    fn sheet_ray(&self, ray: &IndexRay, zlo: usize, zhi: usize) -> Option<SheetRay> {
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

/// One ray on a column sheet: plane offsets `m0..=m1`, z index `z0 + m·dz`, mm per plane `step`.
struct SheetRay {
    m0: usize,
    m1: usize,
    z0: f32,
    dz: f32,
    step: f32,
}

/// How one detector pixel's ray is traced.
enum RowPlan {
    Sheet(SheetRay),
    Walk(RayWalk),
    Miss,
}

/// A column sheet: `planes` rows of `h` z-samples covering `[zlo − 1, zhi + 1]` (the end rows stay
/// zero), plus `LANES − 1` rows of slack for the vector sampler.
struct Sheet {
    data: Vec<f32>,
    /// Per plane: volume offset at z = `zlo` and weight of the two horizontal neighbours.
    taps: Vec<[(usize, f32); 2]>,
    h: usize,
    zlo: usize,
    zhi: usize,
}

impl Sheet {
    fn new() -> Sheet {
        Sheet {
            data: Vec::new(),
            taps: Vec::new(),
            h: 0,
            zlo: 0,
            zhi: 0,
        }
    }

    /// Zero the sheet for `planes` planes over z in `[zlo, zhi]`.
    fn reset(&mut self, planes: usize, zlo: usize, zhi: usize) {
        self.h = zhi - zlo + 3;
        self.zlo = zlo;
        self.zhi = zhi;
        self.data.clear();
        self.data.resize((planes + LANES - 1) * self.h, 0.0);
    }

    /// Clamp range of the lower z neighbour: `[zlo − 1, zhi]`.
    fn q_range(&self) -> (i32, i32) {
        (self.zlo as i32 - 1, self.zhi as i32)
    }

    /// Volume offset (at z = `zlo`) and weight of the two horizontal neighbours of every plane;
    /// neighbours outside `jr` (inclusive, within the grid) get weight 0 and offset 0.
    fn corners(&mut self, layout: Layout, c: &ColumnWalk, jr: (usize, usize)) {
        let st = layout.stride;
        self.taps.clear();
        self.taps.extend((0..c.planes()).map(|m| {
            let plane = (c.lo as usize + m) * st[c.k] + self.zlo * st[2];
            c.corners(m).map(|(q, w)| {
                if q < jr.0 as i32 || q > jr.1 as i32 {
                    (0, 0.0)
                } else {
                    (plane + q as usize * st[c.j], w)
                }
            })
        }));
    }

    /// Forward: `S[m][z] = Σ_corners w · V(plane, corner, z)` over the sheet's z-range. With
    /// z-fastest volumes each corner is a contiguous z-line; otherwise the loops run z-outer so
    /// that the volume is read slice by slice.
    fn build(&mut self, vol: &[f32], layout: Layout, c: &ColumnWalk, jr: (usize, usize)) {
        self.corners(layout, c, jr);
        let (h, sz, nzs) = (self.h, layout.stride[2], self.h - 2);
        if sz == 1 {
            for (m, taps) in self.taps.iter().enumerate() {
                let dst = &mut self.data[m * h + 1..m * h + h - 1];
                for &(base, w) in taps.iter().filter(|t| t.1 != 0.0) {
                    for (d, &v) in dst.iter_mut().zip(&vol[base..base + nzs]) {
                        *d += w * v;
                    }
                }
            }
        } else {
            for t in 0..nzs {
                for (m, taps) in self.taps.iter().enumerate() {
                    let [(b0, w0), (b1, w1)] = *taps;
                    self.data[m * h + 1 + t] += w0 * vol[b0 + t * sz] + w1 * vol[b1 + t * sz];
                }
            }
        }
    }

    /// Adjoint of [`Sheet::build`]: scatter the sheet's z-range into `acc`, same taps.
    fn scatter(&mut self, acc: &mut [f32], layout: Layout, c: &ColumnWalk, jr: (usize, usize)) {
        self.corners(layout, c, jr);
        let (h, sz, nzs) = (self.h, layout.stride[2], self.h - 2);
        if sz == 1 {
            for (m, taps) in self.taps.iter().enumerate() {
                let src = &self.data[m * h + 1..m * h + h - 1];
                for &(base, w) in taps.iter().filter(|t| t.1 != 0.0) {
                    for (d, &v) in acc[base..base + nzs].iter_mut().zip(src) {
                        *d += w * v;
                    }
                }
            }
        } else {
            for t in 0..nzs {
                for (m, taps) in self.taps.iter().enumerate() {
                    let v = self.data[m * h + 1 + t];
                    for &(base, w) in taps.iter().filter(|t| t.1 != 0.0) {
                        acc[base + t * sz] += w * v;
                    }
                }
            }
        }
    }

    /// `Σ_m lerp_z(S[m], z0 + m·dz) · step` (scalar).
    fn sample(&self, r: &SheetRay) -> f32 {
        let (qlo, qhi) = self.q_range();
        let mut acc = 0.0f32;
        for m in r.m0..=r.m1 {
            let z = r.z0 + m as f32 * r.dz;
            let q = floorish(z).clamp(qlo, qhi);
            let f = z - q as f32;
            let idx = m * self.h + (q - qlo) as usize;
            let (a, b) = (self.data[idx], self.data[idx + 1]);
            acc += a + f * (b - a);
        }
        acc * r.step
    }

    /// Adjoint of [`Sheet::sample`]: add `val · step` times the sample weights into the sheet.
    fn spread(&mut self, r: &SheetRay, val: f32) {
        let (qlo, qhi) = self.q_range();
        let w = val * r.step;
        for m in r.m0..=r.m1 {
            let z = r.z0 + m as f32 * r.dz;
            let q = floorish(z).clamp(qlo, qhi);
            let f = z - q as f32;
            let idx = m * self.h + (q - qlo) as usize;
            let wf = w * f;
            self.data[idx] += w - wf;
            self.data[idx + 1] += wf;
        }
    }

    /// [`Sheet::sample`] eight planes at a time with AVX2 gathers (same positions and weights).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn sample_avx2(&self, r: &SheetRay) -> f32 {
        use std::arch::x86_64::*;
        let (qlo, qhi) = self.q_range();
        let h = self.h;
        // Lanes past m1 are clamped into the slack rows and masked out: every index below stays
        // under (m1 + LANES)·h ≤ data.len(), which also fits i32.
        assert!(
            (r.m1 + LANES) * h <= self.data.len() && self.data.len() <= i32::MAX as usize,
            "sheet too small for the ray"
        );
        let ptr = self.data.as_ptr();
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let lane_h = _mm256_mullo_epi32(lane, _mm256_set1_epi32(h as i32));
        let (z0, dz) = (_mm256_set1_ps(r.z0), _mm256_set1_ps(r.dz));
        let half = _mm256_set1_ps(0.5);
        let magic = _mm256_set1_ps(MAGIC);
        let magic_bits = _mm256_set1_epi32(MAGIC.to_bits() as i32);
        let (lo, hi) = (_mm256_set1_epi32(qlo), _mm256_set1_epi32(qhi));
        let end = _mm256_set1_epi32(r.m1 as i32 + 1);
        let mut acc = _mm256_setzero_ps();
        let mut m = r.m0;
        while m <= r.m1 {
            let mi = _mm256_add_epi32(_mm256_set1_epi32(m as i32), lane);
            // Same arithmetic as the scalar path: z = z0 + m·dz, q = floorish(z) clamped.
            let z = _mm256_add_ps(z0, _mm256_mul_ps(_mm256_cvtepi32_ps(mi), dz));
            let t = _mm256_add_ps(_mm256_sub_ps(z, half), magic);
            let q = _mm256_sub_epi32(_mm256_castps_si256(t), magic_bits);
            let q = _mm256_min_epi32(_mm256_max_epi32(q, lo), hi);
            let f = _mm256_sub_ps(z, _mm256_cvtepi32_ps(q));
            let idx = _mm256_add_epi32(
                _mm256_add_epi32(_mm256_set1_epi32((m * h) as i32), lane_h),
                _mm256_sub_epi32(q, lo),
            );
            // SAFETY: idx + 1 < (m1 + LANES)·h ≤ data.len() (asserted above) for every lane.
            let (a, b) = unsafe {
                (
                    _mm256_i32gather_ps::<4>(ptr, idx),
                    _mm256_i32gather_ps::<4>(ptr.add(1), idx),
                )
            };
            let v = _mm256_fmadd_ps(f, _mm256_sub_ps(b, a), a);
            let valid = _mm256_castsi256_ps(_mm256_cmpgt_epi32(end, mi));
            acc = _mm256_add_ps(acc, _mm256_and_ps(v, valid));
            m += LANES;
        }
        let s = _mm_add_ps(_mm256_castps256_ps128(acc), _mm256_extractf128_ps::<1>(acc));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        let s = _mm_add_ss(s, _mm_shuffle_ps::<1>(s, s));
        _mm_cvtss_f32(s) * r.step
    }
}

/// Whether the running CPU has AVX2 and FMA (checked once).
pub(crate) fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *HAS.get_or_init(|| is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

impl Joseph {
    /// Bind a projector to `geometry` (validated).
    pub fn new(geometry: &Geometry) -> Result<Self> {
        geometry.validate()?;
        Ok(Joseph {
            cameras: geometry.cameras(),
            geometry: geometry.clone(),
            simd: has_avx2_fma(),
            sheets: true,
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
        let dims = self.dims();
        let vol = volume.as_standard_layout();
        let vol = vol.as_slice().expect("standard layout");
        let shape = self.projection_shape(views.len());
        let Some(support) = support(vol, dims) else {
            return Ok(Array3::zeros(shape)); // an all-zero volume projects to zero
        };
        let (rows, cols) = (shape[1], shape[2]);
        let copy;
        let (src, layout) = if views.len() >= TRANSPOSE_MIN_VIEWS {
            copy = to_yxz(vol, dims);
            (&copy[..], Layout::yxz(dims))
        } else {
            (vol, Layout::zyx(dims))
        };
        // Detector columns `[view][col][row]`, one task per column.
        let mut columns = vec![0.0f32; views.len() * cols * rows];
        columns
            .par_chunks_mut(rows)
            .enumerate()
            .for_each_init(Sheet::new, |sheet, (line, out)| {
                let cam = &self.cameras[views[line / cols]];
                self.project_column(cam, line % cols, src, layout, &support, sheet, out);
            });
        let out = swap_last(&columns, cols, rows);
        Ok(Array3::from_shape_vec(shape, out).expect("projection shape"))
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
        let dims = self.dims();
        let n = g.len();
        let proj = projections.as_standard_layout();
        let proj = proj.as_slice().expect("standard layout");
        let (rows, cols) = (want[1], want[2]);
        let columns = swap_last(proj, rows, cols);
        let lines = views.len() * cols;
        let full: Support = ([0; 3], [g.nx - 1, g.ny - 1, g.nz - 1]);
        let transposed = views.len() >= TRANSPOSE_MIN_VIEWS;
        let layout = if transposed {
            Layout::yxz(dims)
        } else {
            Layout::zyx(dims)
        };
        // One accumulator per task over runs of detector columns, one task per thread.
        let min_len = lines.div_ceil(rayon::current_num_threads()).max(1);
        let partial: Vec<Vec<f32>> = (0..lines)
            .into_par_iter()
            .with_min_len(min_len)
            .fold(
                || (vec![0.0f32; n], Sheet::new()),
                |(mut acc, mut sheet), line| {
                    let vals = &columns[line * rows..(line + 1) * rows];
                    if vals.iter().any(|&v| v != 0.0) {
                        let cam = &self.cameras[views[line / cols]];
                        self.adjoint_column(
                            cam,
                            line % cols,
                            vals,
                            &mut acc,
                            layout,
                            &full,
                            &mut sheet,
                        );
                    }
                    (acc, sheet)
                },
            )
            .map(|(acc, _)| acc)
            .collect();
        let summed = reduce(partial, n);
        let out = if transposed {
            from_yxz(&summed, dims)
        } else {
            summed
        };
        Ok(Array3::from_shape_vec(g.shape_zyx(), out).expect("grid shape"))
    }

    /// Ray length inside the volume per pixel, `A·1`: the row sums of the system matrix.
    pub fn ray_lengths(&self, views: &[usize]) -> Result<Array3<f32>> {
        let ones = Array3::<f32>::ones(self.geometry.volume.shape_zyx());
        self.forward_views(ones.view(), views)
    }

    /// Grid size `[nx, ny, nz]`.
    fn dims(&self) -> [usize; 3] {
        let g = &self.geometry.volume;
        [g.nx, g.ny, g.nz]
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

    /// The rays of detector column `col` in continuous voxel-index space.
    fn column_rays(&self, cam: &Camera, col: usize) -> ColumnRays {
        let grid = &self.geometry.volume;
        let ends = |row: f64| {
            let end = cam.pixel_camera(col as f64, row);
            let start = match cam.projection {
                Projection::Cone => [0.0; 3],
                Projection::Parallel => [end[0], end[1], 0.0],
            };
            let (o, e) = (cam.to_world(start), cam.to_world(end));
            let (a, b) = (grid.world_to_index(o), grid.world_to_index(e));
            (
                a,
                [0, 1, 2].map(|i| b[i] - a[i]),
                [0, 1, 2].map(|i| e[i] - o[i]),
            )
        };
        let (r0, r1) = (ends(0.0), ends(1.0));
        let pair = |p: [f64; 3], q: [f64; 3]| [p, [0, 1, 2].map(|i| q[i] - p[i])];
        ColumnRays {
            a: pair(r0.0, r1.0),
            g: pair(r0.1, r1.1),
            d: pair(r0.2, r1.2),
        }
    }

    /// The horizontal walk shared by column `col`'s rays, clipped to `support` in x and y, or
    /// `None` when sheets are off or the column's rays are not coplanar with z (then every row
    /// takes the general walk; cameras built by [`Geometry`] always have vertical columns).
    fn column_walk(
        &self,
        cam: &Camera,
        rays: &ColumnRays,
        support: &Support,
    ) -> Option<ColumnWalk> {
        if !self.sheets || cam.rotation[1][0] != 0.0 || cam.rotation[1][1] != 0.0 {
            return None;
        }
        let ray = rays.ray(0);
        let (a, g) = (&ray.a, &ray.g);
        let k = if g[0].abs() > g[1].abs() { 0 } else { 1 };
        let j = 1 - k;
        if g[k] == 0.0 {
            return None;
        }
        let (blo, bhi) = (support.0.map(|x| x as f64), support.1.map(|x| x as f64));
        let mut t = clip(a[k], g[k], blo[k] - 0.5, bhi[k] + 0.5, (0.0, 1.0));
        t = clip(a[j], g[j], blo[j] - 1.0, bhi[j] + 1.0, t);
        let (ka, kb) = (a[k] + t.0 * g[k], a[k] + t.1 * g[k]);
        let (lo, hi) = if t.1 <= t.0 {
            (1, 0)
        } else {
            (
                ka.min(kb).ceil().max(blo[k]) as i64,
                (ka.max(kb).floor() as i64).min(bhi[k] as i64),
            )
        };
        let dp = g[j] / g[k];
        Some(ColumnWalk {
            k,
            j,
            lo,
            hi,
            p0: (a[j] + (lo as f64 - a[k]) * dp) as f32,
            dp: dp as f32,
        })
    }

    /// How the ray through (col, row) is traced: on the column sheet when its dominant axis is
    /// the column's horizontal one, else by the general walk.
    fn plan_row(ray: &IndexRay, column: Option<&ColumnWalk>, support: &Support) -> RowPlan {
        let plan = match column {
            Some(c) if ray.g[2].abs() < ray.g[c.k].abs() => {
                if c.lo > c.hi {
                    None
                } else {
                    c.sheet_ray(ray, support.0[2], support.1[2])
                        .map(RowPlan::Sheet)
                }
            }
            _ => walk(ray, dominant(&ray.g), support).map(RowPlan::Walk),
        };
        plan.unwrap_or(RowPlan::Miss)
    }

    /// Forward-project one detector column into `out` (its rows), compiled for AVX2+FMA when
    /// the CPU has them (ray setup, sheet build and sampling all in one function).
    #[allow(clippy::too_many_arguments)]
    fn project_column(
        &self,
        cam: &Camera,
        col: usize,
        vol: &[f32],
        layout: Layout,
        support: &Support,
        sheet: &mut Sheet,
        out: &mut [f32],
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is only set when the CPU has AVX2 and FMA.
            return unsafe { self.project_column_avx2(cam, col, vol, layout, support, sheet, out) };
        }
        self.project_column_body(cam, col, vol, layout, support, sheet, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    fn project_column_avx2(
        &self,
        cam: &Camera,
        col: usize,
        vol: &[f32],
        layout: Layout,
        support: &Support,
        sheet: &mut Sheet,
        out: &mut [f32],
    ) {
        self.project_column_body(cam, col, vol, layout, support, sheet, out)
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn project_column_body(
        &self,
        cam: &Camera,
        col: usize,
        vol: &[f32],
        layout: Layout,
        support: &Support,
        sheet: &mut Sheet,
        out: &mut [f32],
    ) {
        let rays = self.column_rays(cam, col);
        let column = self.column_walk(cam, &rays, support);
        let mut built = false;
        for (row, o) in out.iter_mut().enumerate() {
            match Self::plan_row(&rays.ray(row), column.as_ref(), support) {
                RowPlan::Sheet(r) => {
                    let c = column.as_ref().expect("sheet rows have a column walk");
                    if !built {
                        sheet.reset(c.planes(), support.0[2], support.1[2]);
                        sheet.build(vol, layout, c, (support.0[c.j], support.1[c.j]));
                        built = true;
                    }
                    *o = self.sample(sheet, &r);
                }
                RowPlan::Walk(w) => {
                    let mut acc = Gather { vol, sum: 0.0 };
                    run(&w, self.dims(), layout, &mut acc);
                    *o = acc.sum * w.step;
                }
                RowPlan::Miss => {}
            }
        }
    }

    /// Adjoint of [`Joseph::project_column`]: add column `col`'s rows `vals` into `acc`
    /// (compiled for AVX2+FMA when the CPU has them; the arithmetic is the same on both paths).
    #[allow(clippy::too_many_arguments)]
    fn adjoint_column(
        &self,
        cam: &Camera,
        col: usize,
        vals: &[f32],
        acc: &mut [f32],
        layout: Layout,
        full: &Support,
        sheet: &mut Sheet,
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is only set when the CPU has AVX2 and FMA.
            return unsafe { self.adjoint_column_avx2(cam, col, vals, acc, layout, full, sheet) };
        }
        self.adjoint_column_body(cam, col, vals, acc, layout, full, sheet)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    fn adjoint_column_avx2(
        &self,
        cam: &Camera,
        col: usize,
        vals: &[f32],
        acc: &mut [f32],
        layout: Layout,
        full: &Support,
        sheet: &mut Sheet,
    ) {
        self.adjoint_column_body(cam, col, vals, acc, layout, full, sheet)
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn adjoint_column_body(
        &self,
        cam: &Camera,
        col: usize,
        vals: &[f32],
        acc: &mut [f32],
        layout: Layout,
        full: &Support,
        sheet: &mut Sheet,
    ) {
        let rays = self.column_rays(cam, col);
        let column = self.column_walk(cam, &rays, full);
        let mut used = false;
        for (row, &val) in vals.iter().enumerate() {
            if val == 0.0 {
                continue;
            }
            match Self::plan_row(&rays.ray(row), column.as_ref(), full) {
                RowPlan::Sheet(r) => {
                    let c = column.as_ref().expect("sheet rows have a column walk");
                    if !used {
                        sheet.reset(c.planes(), full.0[2], full.1[2]);
                        used = true;
                    }
                    sheet.spread(&r, val);
                }
                RowPlan::Walk(w) => {
                    let mut s = Scatter {
                        acc: &mut *acc,
                        val: val * w.step,
                    };
                    run(&w, self.dims(), layout, &mut s);
                }
                RowPlan::Miss => {}
            }
        }
        if used {
            let c = column.as_ref().expect("sheet rows have a column walk");
            sheet.scatter(acc, layout, c, (full.0[c.j], full.1[c.j]));
        }
    }

    /// One ray's sum over its sheet, with the vector sampler where available.
    fn sample(&self, sheet: &Sheet, r: &SheetRay) -> f32 {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is only set when the CPU has AVX2 and FMA.
            return unsafe { sheet.sample_avx2(r) };
        }
        sheet.sample(r)
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
fn run<V: Visit>(walk: &RayWalk, dims: [usize; 3], layout: Layout, v: &mut V) {
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
