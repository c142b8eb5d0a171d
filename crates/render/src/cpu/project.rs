//! Projection of Gaussians onto the detector of each view: forward and backward.
//!
//! Per view, every Gaussian is prepared once in f64 ([`gm::splat`] or [`gm::exact_splat`]) and
//! binned into 16×16 tiles; the prepared geometry is shared by all M density channels. A pixel
//! receives a Gaussian iff it lies within the Mahalanobis cut-off (affine: of the 2D footprint;
//! exact: of the ray's closest approach) — a relative criterion, unlike upstream's absolute
//! `ρμG < 1e-5` skip, so densities of 1e-8 still render.
//!
//! The affine preparation (f32 pixel splats, [`project_prepare`]) can be computed once and read
//! by both passes ([`project_forward_prepared`], [`project_backward_prepared`]); the Burn ops do
//! so. The affine backward evaluates `G` once per (pixel, Gaussian) in 8-lane blocks
//! ([`super::lanes`], AVX2+FMA when the CPU has it), accumulates per-(tile, Gaussian)
//! image-space sums in registers, writes them once, and chains them per Gaussian through
//! [`gm::splat_backward_with`] (one f64 splat per Gaussian); the exact backward accumulates
//! per-pixel `∂/∂(centre, Σ⁻¹)`.

use rayon::prelude::*;

use super::GaussianSlices;
#[cfg(target_arch = "x86_64")]
use super::lanes::Avx2;
use super::lanes::{LANES, Lanes, Portable, dispatched, has_avx2};
use super::tiles::{Bins, TileBox, tile_span};
use crate::camera::Camera;
use crate::gaussian_math::{
    self as gm, ExactSplat, GaussianGeom, SplatGrad, camera_ray, exact_splat, exact_splat_backward,
    line_integral_backward, ray_terms, sym_pack, sym_unpack,
};
use crate::options::{ProjectOptions, ProjectionMode};

/// Detector tile edge in pixels.
pub const TILE: usize = 16;

/// `[0, 1, …, TILE − 1]` as f32: pixel offsets within a row without int→float conversions
/// (which would keep the row loops from vectorising).
const IOTA: [f32; TILE] = {
    let mut a = [0.0f32; TILE];
    let mut i = 0;
    while i < TILE {
        a[i] = i as f32;
        i += 1;
    }
    a
};

/// Gradients of a projection with respect to every input, row-major like the inputs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProjectGrads {
    pub means: Vec<f32>,
    pub scales: Vec<f32>,
    pub rotations: Vec<f32>,
    pub densities: Vec<f32>,
    /// `∂L/∂(screen offset)` per view and Gaussian, `[V, K, 2]` in pixels⁻¹: the projected-centre
    /// gradient that densification thresholds.
    pub screen: Vec<f32>,
}

/// An affine splat reduced to what the pixel loop reads (f32), with its clamped pixel box.
#[derive(Clone, Copy, Debug)]
struct PixelSplat {
    mx: f32,
    my: f32,
    a: f32,
    beta: f32,
    gamma: f32,
    /// Integration factor μ (length units), so a tile's pass reads one array per Gaussian.
    mu: f32,
    /// Pixel box `[x0, x1) × [y0, y1)` clamped to the detector.
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
}

/// Width of one Gaussian's record in a prepared-state buffer (see [`project_prepare`]).
pub const PREPARED_WIDTH: usize = 10;

impl PixelSplat {
    /// `[mx, my, a, β, γ, μ, x0, x1, y0, y1]`; a culled Gaussian is all zeros (an empty box).
    /// Box bounds are below 2²⁰ (the detector limit), so exact in f32.
    fn pack(s: Option<&PixelSplat>) -> [f32; PREPARED_WIDTH] {
        s.map_or([0.0; PREPARED_WIDTH], |s| {
            [
                s.mx,
                s.my,
                s.a,
                s.beta,
                s.gamma,
                s.mu,
                s.x0 as f32,
                s.x1 as f32,
                s.y0 as f32,
                s.y1 as f32,
            ]
        })
    }

    /// Inverse of [`PixelSplat::pack`], with the box clamped to `det` (so a record made for
    /// another detector cannot index outside this one) and its tile box; `None` if culled.
    fn unpack(v: &[f32], det: &Detector) -> Option<(PixelSplat, TileBox)> {
        // `as` saturates (NaN → 0), so the clamped box is always a valid index range.
        let x0 = v[6] as usize;
        let x1 = (v[7] as usize).min(det.cols);
        let y0 = v[8] as usize;
        let y1 = (v[9] as usize).min(det.rows);
        if x0 >= x1 || y0 >= y1 {
            return None;
        }
        let s = PixelSplat {
            mx: v[0],
            my: v[1],
            a: v[2],
            beta: v[3],
            gamma: v[4],
            mu: v[5],
            x0: x0 as u32,
            x1: x1 as u32,
            y0: y0 as u32,
            y1: y1 as u32,
        };
        let tb = TileBox {
            lo: [x0 / TILE, y0 / TILE, 0],
            hi: [(x1 - 1) / TILE + 1, (y1 - 1) / TILE + 1, 1],
        };
        Some((s, tb))
    }
}

struct Detector {
    rows: usize,
    cols: usize,
    tiles_x: usize,
    tiles_y: usize,
}

impl Detector {
    fn new(cam: &Camera) -> Self {
        Self {
            rows: cam.rows,
            cols: cam.cols,
            tiles_x: cam.cols.div_ceil(TILE),
            tiles_y: cam.rows.div_ceil(TILE),
        }
    }

    fn tile_rect(&self, t: usize) -> (usize, usize, usize, usize) {
        let (tx, ty) = (t % self.tiles_x, t / self.tiles_x);
        let x0 = tx * TILE;
        let y0 = ty * TILE;
        (
            x0,
            (x0 + TILE).min(self.cols),
            y0,
            (y0 + TILE).min(self.rows),
        )
    }

    /// Pixel and tile boxes of a footprint `[col_min, col_max] × [row_min, row_max]`.
    fn boxes(&self, bb: [f64; 4]) -> Option<([usize; 4], TileBox)> {
        let (x0, x1, tx0, tx1) = tile_span(bb[0], bb[1], self.cols, TILE)?;
        let (y0, y1, ty0, ty1) = tile_span(bb[2], bb[3], self.rows, TILE)?;
        Some((
            [x0, x1, y0, y1],
            TileBox {
                lo: [tx0, ty0, 0],
                hi: [tx1, ty1, 1],
            },
        ))
    }
}

/// Per-view preparation of every Gaussian.
enum Prepared {
    /// Pixel splats (the chain rule recomputes the f64 splat it needs).
    Affine(Vec<Option<PixelSplat>>),
    Exact(Vec<Option<(ExactSplat, [usize; 4])>>),
}

fn screen_offset(screen: &[f32], k: usize, view: usize, i: usize) -> [f64; 2] {
    let o = 2 * (view * k + i);
    [screen[o] as f64, screen[o + 1] as f64]
}

/// The affine pixel splat (f32) and tile box of Gaussian `i` in `view`, or `None` if it is
/// culled (non-finite density, degenerate, behind the near plane, off the detector).
fn affine_splat(
    g: &GaussianSlices,
    screen: &[f32],
    view: usize,
    i: usize,
    cam: &Camera,
    det: &Detector,
    opts: &ProjectOptions,
) -> Option<(PixelSplat, TileBox)> {
    g.densities_of(i)?;
    let off = screen_offset(screen, g.len(), view, i);
    let near = opts.near_fraction * cam.sdd;
    let s = gm::splat(&g.geom(i), cam, off, opts.cutoff, near)?;
    let bb = [
        s.mean[0] - s.half_extent[0],
        s.mean[0] + s.half_extent[0],
        s.mean[1] - s.half_extent[1],
        s.mean[1] + s.half_extent[1],
    ];
    let (px, tb) = det.boxes(bb)?;
    let ps = PixelSplat {
        mx: s.mean[0] as f32,
        my: s.mean[1] as f32,
        a: s.conic.a as f32,
        beta: s.conic.beta as f32,
        gamma: s.conic.gamma as f32,
        mu: s.mu as f32,
        x0: px[0] as u32,
        x1: px[1] as u32,
        y0: px[2] as u32,
        y1: px[3] as u32,
    };
    (ps.a.is_finite() && ps.beta.is_finite() && ps.gamma.is_finite()).then_some((ps, tb))
}

/// Prepared state of every view and Gaussian, `[V, K, PREPARED_WIDTH]` (f32): the affine pixel
/// splats ([`PixelSplat::pack`]) that [`project_forward_prepared`] and
/// [`project_backward_prepared`] read instead of recomputing them, so one forward and its
/// backward prepare every Gaussian once. Exact mode keeps its f64 preparation internal (f32
/// would lose the per-ray accuracy it exists for): its prepared state is zeros, ignored.
pub fn project_prepare(
    g: &GaussianSlices,
    screen: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    let k = g.len();
    let mut out = vec![0.0f32; cams.len() * k * PREPARED_WIDTH];
    if opts.mode == ProjectionMode::Exact || k == 0 {
        return out;
    }
    for (v, cam) in cams.iter().enumerate() {
        let det = Detector::new(cam);
        out[v * k * PREPARED_WIDTH..(v + 1) * k * PREPARED_WIDTH]
            .par_chunks_mut(PREPARED_WIDTH)
            .enumerate()
            .with_min_len(64)
            .for_each(|(i, rec)| {
                let s = affine_splat(g, screen, v, i, cam, &det, opts);
                rec.copy_from_slice(&PixelSplat::pack(s.as_ref().map(|(s, _)| s)));
            });
    }
    out
}

/// The preparation of `view`: unpacked from `prepared` (affine, see [`project_prepare`]) or
/// computed (exact, or affine without a prepared state); with every Gaussian's tile box.
fn prepare(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: Option<&[f32]>,
    view: usize,
    cam: &Camera,
    opts: &ProjectOptions,
) -> (Prepared, Vec<Option<TileBox>>) {
    let k = g.len();
    let det = Detector::new(cam);
    match opts.mode {
        ProjectionMode::Affine => {
            // Split in the pool (no intermediate Vec, no serial unzip).
            let split = |it: Option<(PixelSplat, TileBox)>| {
                it.map_or((None, None), |(s, b)| (Some(s), Some(b)))
            };
            let (splats, boxes) = match prepared {
                Some(p) => p[view * k * PREPARED_WIDTH..(view + 1) * k * PREPARED_WIDTH]
                    .par_chunks(PREPARED_WIDTH)
                    .with_min_len(256)
                    .map(|rec| split(PixelSplat::unpack(rec, &det)))
                    .unzip(),
                None => (0..k)
                    .into_par_iter()
                    .with_min_len(64)
                    .map(|i| split(affine_splat(g, screen, view, i, cam, &det, opts)))
                    .unzip(),
            };
            (Prepared::Affine(splats), boxes)
        }
        ProjectionMode::Exact => {
            let (splats, boxes) = (0..k)
                .into_par_iter()
                .map(|i| {
                    if g.densities_of(i).is_none() {
                        return (None, None);
                    }
                    let off = screen_offset(screen, k, view, i);
                    let Some(s) = exact_splat(&g.geom(i), cam, off, opts.cutoff) else {
                        return (None, None);
                    };
                    match det.boxes(s.bbox) {
                        Some((px, tb)) => (Some((s, px)), Some(tb)),
                        None => (None, None),
                    }
                })
                .unzip();
            (Prepared::Exact(splats), boxes)
        }
    }
}

/// Column span `[xs, xe)` of row `dy` (pixels from the centre) inside the cut-off ellipse
/// `a (dx + β dy)² + γ dy² ≤ cut²`, clamped to `[x0, x1)`; widened by one pixel each side so
/// rounding never drops a pixel the per-pixel test would keep.
#[inline(always)]
fn row_span(s: &PixelSplat, dy: f32, cut2: f32, x0: usize, x1: usize) -> Option<(usize, usize)> {
    let rem = cut2 - s.gamma * dy * dy;
    if rem.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let half = (rem / s.a).sqrt();
    let c = s.mx - s.beta * dy;
    let lo = ((c - half).floor() - 1.0).max(x0 as f32);
    let hi = ((c + half).ceil() + 2.0).min(x1 as f32);
    (lo < hi).then_some((lo as usize, hi as usize))
}

/// Tile-buffer elements per channel: rows are stored `TILE` wide whatever the tile's width (the
/// columns past a detector edge stay 0), so every row loop has the fixed trip count `TILE`.
const TILE_PIXELS: usize = TILE * TILE;

/// Pixel box `[x0, x1) × [y0, y1)` of `s` clipped to tile rect `r`, or `None` if empty.
#[inline(always)]
fn clip(s: &PixelSplat, r: (usize, usize, usize, usize)) -> Option<(usize, usize, usize, usize)> {
    let (x0, x1) = ((s.x0 as usize).max(r.0), (s.x1 as usize).min(r.1));
    let (y0, y1) = ((s.y0 as usize).max(r.2), (s.y1 as usize).min(r.3));
    (x0 < x1 && y0 < y1).then_some((x0, x1, y0, y1))
}

/// `γ dy²` of row `dy` (pixels from the centre), or `None` if the row misses the cut-off ellipse
/// (`γ dy² ≥ cut²`, or NaN).
#[inline(always)]
fn row_gdy(s: &PixelSplat, dy: f32, cut2: f32) -> Option<f32> {
    let gdy = s.gamma * dy * dy;
    ((cut2 - gdy).partial_cmp(&0.0) == Some(std::cmp::Ordering::Greater)).then_some(gdy)
}

/// The per-(splat, tile, column block) constants of [`SplatBlock::row`].
#[derive(Clone, Copy)]
struct SplatBlock<L> {
    /// Column offsets `x − mx` of the block's lanes (pixels).
    dx: L,
    /// `−½ a`.
    neg_half_a: L,
    /// `−½ cut²` on the splat's clipped columns and `+∞` elsewhere, so one compare applies both
    /// the cut-off and the clipping.
    neg_half_cut: L,
}

impl<L: Lanes> SplatBlock<L> {
    /// Block of tile lanes `h..h + HALF` of a tile starting at column `c0`, for a splat clipped
    /// to tile lanes `[l0, l1)`.
    #[inline(always)]
    fn new(s: &PixelSplat, c0: usize, h: usize, (l0, l1): (usize, usize), cut2: f32) -> Self {
        let cut: [f32; HALF] = std::array::from_fn(|j| {
            if (l0..l1).contains(&(h + j)) {
                -0.5 * cut2
            } else {
                f32::INFINITY
            }
        });
        Self {
            dx: L::splat(c0 as f32 - s.mx).add(L::load(block(&IOTA, h))),
            neg_half_a: L::splat(-0.5 * s.a),
            neg_half_cut: L::load(&cut),
        }
    }

    /// `G = exp(−½ dᵀ Σ₂D⁻¹ d)` on the block's lanes of row `dy = y − my` (pixels), exactly +0
    /// beyond the cut-off (`dᵀ Σ₂D⁻¹ d > cut²`), outside the clipped columns and where the form
    /// is NaN; `gdy` from [`row_gdy`]. The quadratic form is `a (dx + β dy)² + γ dy²`
    /// (cancellation-free), and every lane is evaluated with masks instead of a variable-length
    /// loop over the row's chord: no scalar remainder, no per-row square root or division.
    #[inline(always)]
    fn row(&self, s: &PixelSplat, dy: f32, gdy: f32) -> L {
        let d = self.dx.add(L::splat(s.beta * dy));
        // −½q directly (scaling by −½ is exact, so this is bit-identical to forming q first,
        // one multiply shorter); q ≤ cut² ⟺ −½cut² ≤ −½q.
        let nhq = self.neg_half_a.mul(d).mul_add(d, L::splat(-0.5 * gdy));
        nhq.exp_neg().keep_le(self.neg_half_cut, nhq)
    }
}

/// Lanes per evaluation block of the row kernels: one AVX2 register of f32.
const HALF: usize = LANES;
const _: () = assert!(TILE == 2 * HALF);

/// First lanes of the `HALF`-lane blocks that hold tile columns `[l0, l1)` (`l1 ≤ TILE`).
#[inline(always)]
fn half_range(l0: usize, l1: usize) -> std::iter::StepBy<std::ops::Range<usize>> {
    (l0 / HALF * HALF..l1).step_by(HALF)
}

dispatched! {
    /// Forward splat of `s` into the tile buffer `buf` (`[M][tile pixels]`) of tile rect `r`
    /// with per-channel weights `w[c] = ρ_c μ`.
    fn splat_forward(
        s: &PixelSplat,
        r: (usize, usize, usize, usize),
        cut2: f32,
        w: &[f32],
        buf: &mut [f32],
    ) {
        let Some((x0, x1, y0, y1)) = clip(s, r) else {
            return;
        };
        let lanes = (x0 - r.0, x1 - r.0);
        let finite = w.iter().all(|w| w.is_finite());
        for h in half_range(lanes.0, lanes.1) {
            let sb = SplatBlock::<L>::new(s, r.0, h, lanes, cut2);
            for y in y0..y1 {
                let dy = y as f32 - s.my;
                let Some(gdy) = row_gdy(s, dy, cut2) else {
                    continue;
                };
                let e = sb.row(s, dy, gdy);
                let p = (y - r.2) * TILE + h;
                for (c, &w) in w.iter().enumerate() {
                    let o = c * TILE_PIXELS + p;
                    let row = block_mut(buf, o);
                    let add = L::splat(w).mul(e).zero_outside(e, finite);
                    L::load(row).add(add).store(row);
                }
            }
        }
    }
}

dispatched! {
    /// Backward partial sums of splat `s` over tile rect `r` into `acc`
    /// (`[S_0..S_{M-1}, Σ wG dx, Σ wG dy, Σ wG dx², Σ wG dxdy, Σ wG dy²]`, see
    /// [`project_backward`]) from the tile's upstream gradient `gt` (`[M][tile pixels]`;
    /// `finite`: every value of it is finite). `rows` is scratch (any contents on entry).
    ///
    /// Per 8-lane column block, two sweeps over the tile rows with register accumulators: the
    /// first evaluates `G` once per pixel, keeps it in `rows` and sums the moments of `w G`
    /// (`w = Σ_c ρ_c g_c`) per column; the second sums `S_c = Σ g_c G` per channel from the kept
    /// `G`. A column's dx is fixed, so the dx moments follow at the reduction:
    /// `Σ wG dx = Σ_col dx·(Σ_rows wG)`, and so on.
    fn splat_backward(
        s: &PixelSplat,
        r: (usize, usize, usize, usize),
        cut2: f32,
        gt: &[f32],
        finite: bool,
        dens: &[f32],
        rows: &mut [[f32; HALF]; TILE],
        acc: &mut [f64],
    ) {
        let m = dens.len();
        // One channel: the first sweep sums the moments of g G instead (ρ factored out and
        // applied after the reduction), whose zeroth moment is S_0 itself: no second sweep.
        let single = m == 1;
        acc.fill(0.0);
        let Some((x0, x1, y0, y1)) = clip(s, r) else {
            return;
        };
        let lanes = (x0 - r.0, x1 - r.0);
        for h in half_range(lanes.0, lanes.1) {
            let sb = SplatBlock::<L>::new(s, r.0, h, lanes, cut2);
            let (mut lw, mut ly, mut lyy) = (L::zero(), L::zero(), L::zero());
            for y in y0..y1 {
                let ty = y - r.2;
                let dy = y as f32 - s.my;
                let e = match row_gdy(s, dy, cut2) {
                    Some(gdy) => sb.row(s, dy, gdy),
                    None => L::zero(),
                };
                let p = ty * TILE + h;
                let u = if single {
                    L::load(block(gt, p))
                } else {
                    e.store(&mut rows[ty]);
                    let mut u = L::zero();
                    for (c, &rho) in dens.iter().enumerate() {
                        u = L::splat(rho).mul_add(L::load(block(gt, c * TILE_PIXELS + p)), u);
                    }
                    u
                };
                let w = e.mul(u).zero_outside(e, finite);
                let wy = w.mul(L::splat(dy));
                lw = lw.add(w);
                ly = ly.add(wy);
                lyy = wy.mul_add(L::splat(dy), lyy);
            }
            let [s0, wx, wxx, wy, wxy, wyy] = L::moments(sb.dx, lw, ly, lyy);
            if single {
                acc[0] += s0;
            } else {
                for c in 0..m {
                    let mut sc = L::zero();
                    for y in y0..y1 {
                        let e = L::load(&rows[y - r.2]);
                        let g = L::load(block(gt, c * TILE_PIXELS + (y - r.2) * TILE + h));
                        sc = sc.add(e.mul(g).zero_outside(e, finite));
                    }
                    acc[c] += sc.sum();
                }
            }
            acc[m] += wx;
            acc[m + 1] += wy;
            acc[m + 2] += wxx;
            acc[m + 3] += wxy;
            acc[m + 4] += wyy;
        }
        if single {
            let rho = dens[0] as f64;
            acc[1..].iter_mut().for_each(|v| *v *= rho);
        }
    }
}

/// The `HALF`-lane block of `v` at offset `o`.
#[inline(always)]
fn block(v: &[f32], o: usize) -> &[f32; HALF] {
    v[o..o + HALF].try_into().expect("HALF-wide block")
}

/// The mutable `HALF`-lane block of `v` at offset `o`.
#[inline(always)]
fn block_mut(v: &mut [f32], o: usize) -> &mut [f32; HALF] {
    (&mut v[o..o + HALF]).try_into().expect("HALF-wide block")
}

/// Visit the pixels of an exact splat inside tile rect `r`: `f(local_index, col, row)`.
#[inline(always)]
fn exact_pixels(
    px: &[usize; 4],
    r: (usize, usize, usize, usize),
    mut f: impl FnMut(usize, usize, usize),
) {
    let (x0, x1) = (px[0].max(r.0), px[1].min(r.1));
    let (y0, y1) = (px[2].max(r.2), px[3].min(r.3));
    for y in y0..y1 {
        for x in x0..x1 {
            f((y - r.2) * TILE + x - r.0, x, y);
        }
    }
}

/// Forward projection: image `[V, M, rows, cols]` of line integrals.
///
/// `screen` holds per-view screen offsets `[V, K, 2]` (pixels) added to the projected centres
/// (zeros in normal use; their gradient is the densification statistic). Every camera must have
/// the same detector size (checked by the caller).
pub fn project_forward(
    g: &GaussianSlices,
    screen: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    forward(g, screen, None, cams, opts)
}

/// [`project_forward`] reading the per-Gaussian preparation from `prepared` (made by
/// [`project_prepare`] from the same inputs). A buffer of the wrong length is ignored (the
/// preparation is then recomputed); boxes are clamped to the detector.
pub fn project_forward_prepared(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    forward(g, screen, fitting(prepared, g, cams), cams, opts)
}

/// `prepared` if it has the length [`project_prepare`] gives for `g` and `cams`.
fn fitting<'a>(prepared: &'a [f32], g: &GaussianSlices, cams: &[Camera]) -> Option<&'a [f32]> {
    (prepared.len() == cams.len() * g.len() * PREPARED_WIDTH).then_some(prepared)
}

fn forward(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: Option<&[f32]>,
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    let m = g.channels;
    let Some(first) = cams.first() else {
        return Vec::new();
    };
    let plane = first.rows * first.cols;
    let mut out = vec![0.0f32; cams.len() * m * plane];
    if g.is_empty() || plane == 0 || m == 0 {
        return out;
    }
    let cut2 = opts.cutoff * opts.cutoff;
    for (v, cam) in cams.iter().enumerate() {
        let det = Detector::new(cam);
        let (prep, boxes) = prepare(g, screen, prepared, v, cam, opts);
        let bins = Bins::tile_lists([det.tiles_x, det.tiles_y, 1], &boxes);
        let tiles: Vec<Vec<f32>> = (0..bins.tiles())
            .into_par_iter()
            .map(|t| {
                let r = det.tile_rect(t);
                let n = TILE_PIXELS;
                let mut buf = vec![0.0f32; m * n];
                let list = &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]];
                match &prep {
                    Prepared::Affine(splats) => {
                        let mut w = vec![0.0f32; m];
                        // Gather the tile's splats first: the cache misses of this tight loop
                        // overlap, unlike misses taken inside the pixel loops.
                        let local: Vec<(usize, PixelSplat)> = list
                            .iter()
                            .filter_map(|&gi| splats[gi as usize].map(|s| (gi as usize, s)))
                            .collect();
                        for &(gi, ref s) in &local {
                            let dens = &g.densities[m * gi..m * gi + m];
                            for c in 0..m {
                                w[c] = dens[c] * s.mu;
                            }
                            splat_forward(s, r, cut2 as f32, &w, &mut buf);
                        }
                    }
                    Prepared::Exact(splats) => {
                        let mut acc = vec![0.0f64; m * n];
                        for &gi in list {
                            let gi = gi as usize;
                            let Some((s, px)) = &splats[gi] else { continue };
                            let dens = &g.densities[m * gi..m * gi + m];
                            exact_pixels(px, r, |p, x, y| {
                                let (o, d, len) = camera_ray(cam, x as f64, y as f64);
                                let Some(rt) = ray_terms(&s.ray_gaussian, o, d) else {
                                    return;
                                };
                                if rt.q > cut2 {
                                    return;
                                }
                                let val = gm::line_integral_terms(&rt, len);
                                for c in 0..m {
                                    acc[c * n + p] += dens[c] as f64 * val;
                                }
                            });
                        }
                        for (b, a) in buf.iter_mut().zip(&acc) {
                            *b = *a as f32;
                        }
                    }
                }
                buf
            })
            .collect();
        let view_out = &mut out[v * m * plane..(v + 1) * m * plane];
        for (t, buf) in tiles.iter().enumerate() {
            let r = det.tile_rect(t);
            let tw = r.1 - r.0;
            let n = TILE_PIXELS;
            for c in 0..m {
                for y in r.2..r.3 {
                    let o = c * n + (y - r.2) * TILE;
                    let src = &buf[o..o + tw];
                    let dst = c * plane + y * det.cols + r.0;
                    view_out[dst..dst + tw].copy_from_slice(src);
                }
            }
        }
    }
    out
}

/// Backward projection: gradients of `L` given `grad = ∂L/∂image` (`[V, M, rows, cols]`).
pub fn project_backward(
    g: &GaussianSlices,
    screen: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
    grad: &[f32],
) -> ProjectGrads {
    backward(g, screen, None, cams, opts, grad)
}

/// [`project_backward`] reading the per-Gaussian preparation from `prepared` (see
/// [`project_forward_prepared`]).
pub fn project_backward_prepared(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
    grad: &[f32],
) -> ProjectGrads {
    backward(g, screen, fitting(prepared, g, cams), cams, opts, grad)
}

fn backward(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: Option<&[f32]>,
    cams: &[Camera],
    opts: &ProjectOptions,
    grad: &[f32],
) -> ProjectGrads {
    let k = g.len();
    let m = g.channels;
    let mut total = ProjectGrads {
        means: vec![0.0; 3 * k],
        scales: vec![0.0; 3 * k],
        rotations: vec![0.0; 4 * k],
        densities: vec![0.0; m * k],
        screen: vec![0.0; 2 * k * cams.len()],
    };
    let Some(first) = cams.first() else {
        return total;
    };
    let plane = first.rows * first.cols;
    if k == 0 || plane == 0 || m == 0 {
        return total;
    }
    let cut2 = opts.cutoff * opts.cutoff;
    for (v, cam) in cams.iter().enumerate() {
        let det = Detector::new(cam);
        let near = opts.near_fraction * cam.sdd;
        let gview = &grad[v * m * plane..(v + 1) * m * plane];
        let (prep, boxes) = prepare(g, screen, prepared, v, cam, opts);
        let bins = Bins::new([det.tiles_x, det.tiles_y, 1], &boxes);
        // Per-slot partial sums. Affine: [S_0..S_{M-1}, Σ wG dx, Σ wG dy, Σ wG dx², Σ wG dxdy,
        // Σ wG dy²] with S_c = Σ g_c G and w = Σ_c ρ_c g_c. Exact: [S_c.., g_centre(3), g_prec(6)].
        let stride = match prep {
            Prepared::Affine(..) => m + 5,
            Prepared::Exact(..) => m + 9,
        };
        let mut slots = vec![0.0f64; bins.isects() * stride];
        let per_tile = bins.split_per_tile(&mut slots, stride);
        per_tile.into_par_iter().enumerate().for_each(|(t, out)| {
            let r = det.tile_rect(t);
            let tw = r.1 - r.0;
            let list = &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]];
            // The tile's upstream gradient, gathered once: [M][pixels].
            let n = TILE_PIXELS;
            let mut gt = vec![0.0f32; m * n];
            for c in 0..m {
                for y in r.2..r.3 {
                    let src = c * plane + y * det.cols + r.0;
                    let o = c * n + (y - r.2) * TILE;
                    gt[o..o + tw].copy_from_slice(&gview[src..src + tw]);
                }
            }
            let finite = gt.iter().all(|v| v.is_finite());
            let mut rows = [[0.0f32; HALF]; TILE];
            // Gather the tile's affine splats first (see the forward pass).
            let local: Vec<Option<PixelSplat>> = match &prep {
                Prepared::Affine(splats) => list.iter().map(|&gi| splats[gi as usize]).collect(),
                Prepared::Exact(_) => Vec::new(),
            };
            for (j, &gi) in list.iter().enumerate() {
                let gi = gi as usize;
                let acc = &mut out[j * stride..(j + 1) * stride];
                let dens = &g.densities[m * gi..m * gi + m];
                match &prep {
                    Prepared::Affine(..) => {
                        let Some(s) = &local[j] else { continue };
                        splat_backward(s, r, cut2 as f32, &gt, finite, dens, &mut rows, acc);
                    }
                    Prepared::Exact(splats) => {
                        let Some((s, px)) = &splats[gi] else { continue };
                        exact_pixels(px, r, |p, x, y| {
                            let (o, d, len) = camera_ray(cam, x as f64, y as f64);
                            let Some(rt) = ray_terms(&s.ray_gaussian, o, d) else {
                                return;
                            };
                            if rt.q > cut2 {
                                return;
                            }
                            let mut w = 0.0f64;
                            for c in 0..m {
                                w += dens[c] as f64 * gt[c * n + p] as f64;
                            }
                            let (val, g_c, g_p) =
                                line_integral_backward(&s.ray_gaussian, o, d, len, w);
                            for c in 0..m {
                                acc[c] += gt[c * n + p] as f64 * val;
                            }
                            for q in 0..3 {
                                acc[m + q] += g_c[q];
                            }
                            let gp = sym_pack(&g_p);
                            for q in 0..6 {
                                acc[m + 3 + q] += gp[q];
                            }
                        });
                    }
                }
            }
        });
        // Gather per Gaussian and chain to its parameters, written straight into the outputs.
        let screen_view = &mut total.screen[2 * v * k..2 * (v + 1) * k];
        total
            .means
            .par_chunks_mut(3)
            .zip(total.scales.par_chunks_mut(3))
            .zip(total.rotations.par_chunks_mut(4))
            .zip(total.densities.par_chunks_mut(m))
            .zip(screen_view.par_chunks_mut(2))
            .enumerate()
            .with_min_len(64)
            .for_each_init(
                || vec![0.0f64; stride],
                |sum, (i, ((((out_mean, out_scale), out_rot), out_dens), out_screen))| {
                    // A Gaussian's slots lie in different tiles' runs (cache misses the f64
                    // chain below would otherwise wait for): fetch those of a later one now.
                    if let Some(&[from, to, ..]) = bins.gaussian_start.get(i + PREFETCH_AHEAD..) {
                        for &slot in &bins.gaussian_isects[from..to] {
                            prefetch(&slots[slot * stride]);
                        }
                    }
                    let isects =
                        &bins.gaussian_isects[bins.gaussian_start[i]..bins.gaussian_start[i + 1]];
                    if isects.is_empty() {
                        return;
                    }
                    sum.fill(0.0);
                    for &slot in isects {
                        for (a, b) in sum
                            .iter_mut()
                            .zip(&slots[slot * stride..(slot + 1) * stride])
                        {
                            *a += b;
                        }
                    }
                    let geom: GaussianGeom = g.geom(i);
                    let dens = &g.densities[m * i..m * i + m];
                    let off = screen_offset(screen, k, v, i);
                    // ∂L/∂ρ_c = dens_scale · S_c.
                    let (geo, dens_scale, g_screen) = match &prep {
                        Prepared::Affine(_) => {
                            let mut mu = 0.0;
                            let image_grad = |sp: &gm::Splat| {
                                mu = sp.mu;
                                let [ca, cb, cc] = sp.conic_mat;
                                let mu = sp.mu;
                                let (wx, wy) = (sum[m], sum[m + 1]);
                                SplatGrad {
                                    mean: [mu * (ca * wx + cb * wy), mu * (cb * wx + cc * wy)],
                                    conic: [
                                        -0.5 * mu * sum[m + 2],
                                        -0.5 * mu * sum[m + 3],
                                        -0.5 * mu * sum[m + 4],
                                    ],
                                    mu: (0..m).map(|c| dens[c] as f64 * sum[c]).sum(),
                                }
                            };
                            let Some((geo, sg)) = gm::splat_backward_with(
                                &geom,
                                cam,
                                off,
                                opts.cutoff,
                                near,
                                image_grad,
                            ) else {
                                return;
                            };
                            (geo, mu, sg.mean)
                        }
                        Prepared::Exact(_) => {
                            let g_centre = [sum[m], sum[m + 1], sum[m + 2]];
                            let gp: [f64; 6] = std::array::from_fn(|q| sum[m + 3 + q]);
                            let (geo, g_screen) =
                                exact_splat_backward(&geom, cam, off, g_centre, &sym_unpack(&gp));
                            (geo, 1.0, g_screen)
                        }
                    };
                    let finite = geo
                        .mean
                        .iter()
                        .chain(&geo.scale)
                        .chain(&geo.quat)
                        .chain(&g_screen)
                        .all(|x| x.is_finite())
                        && sum[..m].iter().all(|x| (dens_scale * x).is_finite());
                    if !finite {
                        return;
                    }
                    for q in 0..3 {
                        out_mean[q] += geo.mean[q] as f32;
                        out_scale[q] += geo.scale[q] as f32;
                    }
                    for q in 0..4 {
                        out_rot[q] += geo.quat[q] as f32;
                    }
                    for c in 0..m {
                        out_dens[c] += (dens_scale * sum[c]) as f32;
                    }
                    out_screen[0] = g_screen[0] as f32;
                    out_screen[1] = g_screen[1] as f32;
                },
            );
    }
    total
}

/// How many Gaussians ahead the backward's per-Gaussian gather prefetches its slots.
const PREFETCH_AHEAD: usize = 4;

/// Hint the CPU to load the cache line holding `v` (no effect on results; no-op off x86-64).
#[inline(always)]
fn prefetch<T>(v: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch never faults nor changes memory, and `v` is a valid reference.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>((v as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}

/// Number of Gaussian–pixel evaluations one forward pass performs (affine: the pixels of each
/// footprint's cut-off rows; exact: every pixel of the footprint box; summed over views) — the
/// work unit of the benchmarks.
pub fn count_project_evaluations(
    g: &GaussianSlices,
    cams: &[Camera],
    opts: &ProjectOptions,
) -> usize {
    let screen = vec![0.0f32; 2 * g.len() * cams.len()];
    let mut total = 0;
    for (v, cam) in cams.iter().enumerate() {
        let (prep, _) = prepare(g, &screen, None, v, cam, opts);
        total += match prep {
            Prepared::Affine(splats) => {
                let cut2 = (opts.cutoff * opts.cutoff) as f32;
                let spans = |s: &PixelSplat| -> usize {
                    (s.y0..s.y1)
                        .filter_map(|y| {
                            row_span(s, y as f32 - s.my, cut2, s.x0 as usize, s.x1 as usize)
                        })
                        .map(|(a, b)| b - a)
                        .sum()
                };
                splats.iter().flatten().map(spans).sum::<usize>()
            }
            Prepared::Exact(splats) => splats
                .iter()
                .flatten()
                .map(|(_, px)| (px[1] - px[0]) * (px[3] - px[2]))
                .sum(),
        };
    }
    total
}
