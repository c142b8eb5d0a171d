//! The row kernels: one splat evaluated over the rows of its pixel box, 8 lanes at a time
//! ([`super::super::lanes`]) in blocks that start at the box's own first column, forward
//! (accumulate into a band of detector rows) and backward (the image-space gradient sums).

use super::*;

/// Column span `[xs, xe)` of row `dy` (pixels from the centre) inside the cut-off ellipse
/// `a (dx + β dy)² + γ dy² ≤ cut²`, clamped to `[x0, x1)`; widened by one pixel each side so
/// rounding never drops a pixel the per-pixel test would keep.
#[inline(always)]
pub(super) fn row_span(
    s: &PixelSplat,
    dy: f32,
    cut2: f32,
    x0: usize,
    x1: usize,
) -> Option<(usize, usize)> {
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

/// `γ dy²` of row `dy` (pixels from the centre), or `None` if the row misses the cut-off ellipse
/// (`γ dy² ≥ cut²`, or NaN).
#[inline(always)]
pub(super) fn row_gdy(s: &PixelSplat, dy: f32, cut2: f32) -> Option<f32> {
    let gdy = s.gamma * dy * dy;
    ((cut2 - gdy).partial_cmp(&0.0) == Some(std::cmp::Ordering::Greater)).then_some(gdy)
}

/// The per-(splat, column block) constants of [`SplatBlock::row`].
#[derive(Clone, Copy)]
pub(super) struct SplatBlock<L> {
    /// Column offsets `x − mx` of the block's lanes (pixels).
    pub(super) dx: L,
    /// `−½ a`.
    pub(super) neg_half_a: L,
    /// `−½ cut²` on the columns inside the splat's box and `+∞` elsewhere, so one compare
    /// applies both the cut-off and the box.
    pub(super) neg_half_cut: L,
}

impl<L: Lanes> SplatBlock<L> {
    /// The block of `s` whose first lane is column `x0` (`s.x0 ≤ x0 < s.x1`).
    #[inline(always)]
    pub(super) fn at(s: &PixelSplat, x0: usize, cut2: f32) -> Self {
        let inside = s.x1 as usize - x0;
        let cut: [f32; HALF] = std::array::from_fn(|j| {
            if j < inside {
                -0.5 * cut2
            } else {
                f32::INFINITY
            }
        });
        Self {
            // Integer columns are exact in f32 (the detector limit is 2²⁰): one rounding.
            dx: L::splat(x0 as f32)
                .add(L::load(&LANE_OFFSETS))
                .add(L::splat(-s.mx)),
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
    pub(super) fn row(&self, s: &PixelSplat, dy: f32, gdy: f32) -> L {
        let d = self.dx.add(L::splat(s.beta * dy));
        // −½q directly (scaling by −½ is exact, so this is bit-identical to forming q first,
        // one multiply shorter); q ≤ cut² ⟺ −½cut² ≤ −½q.
        let nhq = self.neg_half_a.mul(d).mul_add(d, L::splat(-0.5 * gdy));
        nhq.exp_neg().keep_le(self.neg_half_cut, nhq)
    }
}

/// Lanes per evaluation block of the row kernels: one AVX2 register of f32.
pub(super) const HALF: usize = LANES;

/// `[0, 1, …, HALF − 1]` as f32: the lanes' column offsets within a block.
const LANE_OFFSETS: [f32; HALF] = {
    let mut a = [0.0f32; HALF];
    let mut i = 0;
    while i < HALF {
        a[i] = i as f32;
        i += 1;
    }
    a
};

/// Detector rows `[y0, y1)` in a row-padded buffer (`[M][y1 − y0][cols + HALF]`): a forward
/// task's band, or the whole view for the backward's upstream gradient.
#[derive(Clone, Copy)]
pub(super) struct Band {
    pub(super) y0: usize,
    pub(super) y1: usize,
    pub(super) layout: PaddedRows,
}

impl Band {
    pub(super) fn new(det: &Detector, y0: usize, y1: usize) -> Self {
        Self {
            y0,
            y1,
            layout: PaddedRows::new(det.cols, y1 - y0),
        }
    }

    /// Offset of pixel `(x, y)` of channel `c`.
    #[inline(always)]
    pub(super) fn at(&self, c: usize, x: usize, y: usize) -> usize {
        self.layout.at(c, y - self.y0, x)
    }
}

/// Forward splat of `s`'s rows inside `band` into the band's buffer `buf` with per-channel
/// weights `w[c] = ρ_c μ` (inlined into a dispatched pass, which picks `L`).
#[inline(always)]
pub(super) fn splat_forward<L: Lanes>(
    s: &PixelSplat,
    band: Band,
    cut2: f32,
    w: &[f32],
    buf: &mut [f32],
) {
    let rows = (s.y0 as usize).max(band.y0)..(s.y1 as usize).min(band.y1);
    let finite = w.iter().all(|w| w.is_finite());
    for x0 in (s.x0 as usize..s.x1 as usize).step_by(HALF) {
        let sb = SplatBlock::<L>::at(s, x0, cut2);
        for y in rows.clone() {
            let dy = y as f32 - s.my;
            let Some(gdy) = row_gdy(s, dy, cut2) else {
                continue;
            };
            let e = sb.row(s, dy, gdy);
            for (c, &w) in w.iter().enumerate() {
                let row = block_mut(buf, band.at(c, x0, y));
                let add = L::splat(w).mul(e).zero_outside(e, finite);
                L::load(row).add(add).store(row);
            }
        }
    }
}

/// Rows of one lane block summed in f32 before the backward's moments are widened into f64 (16,
/// the tile height that bounded them when the sums were per detector tile).
const FLUSH_ROWS: usize = 16;

/// The upstream gradient of one view as the backward reads it: every row of the detector
/// ([`Band`]), padded.
#[derive(Clone, Copy)]
pub(super) struct ViewGrad<'a> {
    pub(super) values: UpstreamGrad<'a>,
    pub(super) band: Band,
}

/// Widen one block's f32 row sums (`lw`, `ly`, `lyy` and the per-channel `g_c G` in `lanes`)
/// into `acc` and zero them; the block's dx is fixed per lane, so the dx moments follow here:
/// `Σ wG dx = Σ_col dx·(Σ_rows wG)`, and so on.
#[inline(always)]
fn flush<L: Lanes>(dx: L, sums: &mut [L; 3], lanes: &mut [[f32; HALF]], m: usize, acc: &mut [f64]) {
    let [lw, ly, lyy] = *sums;
    let [s0, wx, wxx, wy, wxy, wyy] = L::moments(dx, lw, ly, lyy);
    if m == 1 {
        acc[0] += s0;
    } else {
        drain::<L>(lanes, acc);
    }
    acc[m] += wx;
    acc[m + 1] += wy;
    acc[m + 2] += wxx;
    acc[m + 3] += wxy;
    acc[m + 4] += wyy;
    *sums = [L::zero(); 3];
}

/// Backward sums of splat `s` over its pixel box into `acc` (zero on entry;
/// `[S_0..S_{M-1}, Σ wG dx, Σ wG dy, Σ wG dx², Σ wG dxdy, Σ wG dy²]`, see
/// [`project_backward`]) from the view's upstream gradient `grad`; `lanes` is scratch of `M`
/// lane blocks, zero on entry and on return (inlined into a dispatched pass, which picks `L`).
///
/// The box is walked in lane blocks that start at its own first column (a footprint no
/// wider than a block is read once per row), with register accumulators of the moments of
/// `w G` (`w = Σ_c ρ_c g_c`) and, per channel, `g_c G`, widened every [`FLUSH_ROWS`] rows.
/// With one channel the sums are of `g G`, `ρ` applied at the end (`S_0` is then the zeroth
/// moment itself).
#[inline(always)]
pub(super) fn splat_backward<L: Lanes>(
    s: &PixelSplat,
    cut2: f32,
    grad: ViewGrad<'_>,
    dens: &[f32],
    lanes: &mut [[f32; HALF]],
    acc: &mut [f64],
) {
    let UpstreamGrad { values: gv, finite } = grad.values;
    let m = dens.len();
    let single = m == 1;
    let (x0, x1, y0, y1) = (s.x0 as usize, s.x1 as usize, s.y0 as usize, s.y1 as usize);
    for bx in (x0..x1).step_by(HALF) {
        let sb = SplatBlock::<L>::at(s, bx, cut2);
        let mut sums = [L::zero(); 3];
        let mut batches = RowBatches::new(FLUSH_ROWS);
        for y in y0..y1 {
            let dy = y as f32 - s.my;
            let Some(gdy) = row_gdy(s, dy, cut2) else {
                continue;
            };
            let e = sb.row(s, dy, gdy);
            let u = if single {
                L::load(block(gv, grad.band.at(0, bx, y)))
            } else {
                let mut u = L::zero();
                for (c, &rho) in dens.iter().enumerate() {
                    let gc = L::load(block(gv, grad.band.at(c, bx, y)));
                    let sc = e.mul(gc).zero_outside(e, finite);
                    L::load(&lanes[c]).add(sc).store(&mut lanes[c]);
                    u = L::splat(rho).mul_add(gc, u);
                }
                u
            };
            let w = e.mul(u).zero_outside(e, finite);
            let wy = w.mul(L::splat(dy));
            let [lw, ly, lyy] = &mut sums;
            *lw = lw.add(w);
            *ly = ly.add(wy);
            *lyy = wy.mul_add(L::splat(dy), *lyy);
            if batches.due() {
                flush(sb.dx, &mut sums, lanes, m, acc);
            }
        }
        if batches.pending() {
            flush(sb.dx, &mut sums, lanes, m, acc);
        }
    }
    if single {
        let rho = dens[0] as f64;
        acc[1..].iter_mut().for_each(|v| *v *= rho);
    }
}

/// The `HALF`-lane block of `v` at offset `o`.
#[inline(always)]
pub(super) fn block(v: &[f32], o: usize) -> &[f32; HALF] {
    v[o..o + HALF].try_into().expect("HALF-wide block")
}

/// The mutable `HALF`-lane block of `v` at offset `o`.
#[inline(always)]
pub(super) fn block_mut(v: &mut [f32], o: usize) -> &mut [f32; HALF] {
    (&mut v[o..o + HALF]).try_into().expect("HALF-wide block")
}

/// Visit the pixels of exact splat `s` in its box `px` with rows in `rows` whose ray passes
/// within the cut-off (`q ≤ cut²`): `f(x, y, origin, direction, length, terms)`.
#[inline(always)]
pub(super) fn exact_rays(
    cam: &Camera,
    s: &ExactSplat,
    px: &[usize; 4],
    rows: std::ops::Range<usize>,
    cut2: f64,
    mut f: impl FnMut(usize, usize, [f64; 3], [f64; 3], f64, &gm::RayTerms),
) {
    for y in rows {
        for x in px[0]..px[1] {
            let (o, d, len) = camera_ray(cam, x as f64, y as f64);
            let Some(rt) = ray_terms(&s.ray_gaussian, o, d) else {
                continue;
            };
            // Not `q ≤ cut²`: a NaN q is kept, as the per-ray reference keeps it.
            if rt.q.partial_cmp(&cut2) != Some(std::cmp::Ordering::Greater) {
                f(x, y, o, d, len, &rt);
            }
        }
    }
}
