//! The row kernels: one splat evaluated over the pixels of a tile, 8 lanes at a time
//! ([`super::super::lanes`]), forward (accumulate into the tile) and backward (partial sums of
//! the image-space gradients).

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

/// Tile-buffer elements per channel: rows are stored `TILE` wide whatever the tile's width (the
/// columns past a detector edge stay 0), so every row loop has the fixed trip count `TILE`.
pub(super) const TILE_PIXELS: usize = TILE * TILE;

/// Pixel box `[x0, x1) × [y0, y1)` of `s` clipped to tile rect `r`, or `None` if empty.
#[inline(always)]
pub(super) fn clip(
    s: &PixelSplat,
    r: (usize, usize, usize, usize),
) -> Option<(usize, usize, usize, usize)> {
    let (x0, x1) = ((s.x0 as usize).max(r.0), (s.x1 as usize).min(r.1));
    let (y0, y1) = ((s.y0 as usize).max(r.2), (s.y1 as usize).min(r.3));
    (x0 < x1 && y0 < y1).then_some((x0, x1, y0, y1))
}

/// `γ dy²` of row `dy` (pixels from the centre), or `None` if the row misses the cut-off ellipse
/// (`γ dy² ≥ cut²`, or NaN).
#[inline(always)]
pub(super) fn row_gdy(s: &PixelSplat, dy: f32, cut2: f32) -> Option<f32> {
    let gdy = s.gamma * dy * dy;
    ((cut2 - gdy).partial_cmp(&0.0) == Some(std::cmp::Ordering::Greater)).then_some(gdy)
}

/// The per-(splat, tile, column block) constants of [`SplatBlock::row`].
#[derive(Clone, Copy)]
pub(super) struct SplatBlock<L> {
    /// Column offsets `x − mx` of the block's lanes (pixels).
    pub(super) dx: L,
    /// `−½ a`.
    pub(super) neg_half_a: L,
    /// `−½ cut²` on the splat's clipped columns and `+∞` elsewhere, so one compare applies both
    /// the cut-off and the clipping.
    pub(super) neg_half_cut: L,
}

impl<L: Lanes> SplatBlock<L> {
    /// Block of tile lanes `h..h + HALF` of a tile starting at column `c0`, for a splat clipped
    /// to tile lanes `[l0, l1)`.
    #[inline(always)]
    pub(super) fn new(
        s: &PixelSplat,
        c0: usize,
        h: usize,
        (l0, l1): (usize, usize),
        cut2: f32,
    ) -> Self {
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
const _: () = assert!(TILE == 2 * HALF);

/// First lanes of the `HALF`-lane blocks that hold tile columns `[l0, l1)` (`l1 ≤ TILE`).
#[inline(always)]
pub(super) fn half_range(l0: usize, l1: usize) -> std::iter::StepBy<std::ops::Range<usize>> {
    (l0 / HALF * HALF..l1).step_by(HALF)
}

dispatched! {
    /// Forward splat of `s` into the tile buffer `buf` (`[M][tile pixels]`) of tile rect `r`
    /// with per-channel weights `w[c] = ρ_c μ`.
    pub(super) fn splat_forward(
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
    /// [`project_backward`]) from the tile's upstream gradient `grad` (`[M][tile pixels]`).
    /// `rows` is scratch (any contents on entry).
    ///
    /// Per 8-lane column block, two sweeps over the tile rows with register accumulators: the
    /// first evaluates `G` once per pixel, keeps it in `rows` and sums the moments of `w G`
    /// (`w = Σ_c ρ_c g_c`) per column; the second sums `S_c = Σ g_c G` per channel from the kept
    /// `G`. A column's dx is fixed, so the dx moments follow at the reduction:
    /// `Σ wG dx = Σ_col dx·(Σ_rows wG)`, and so on.
    pub(super) fn splat_backward(
        s: &PixelSplat,
        r: (usize, usize, usize, usize),
        cut2: f32,
        grad: TileGrad<'_>,
        dens: &[f32],
        rows: &mut [[f32; HALF]; TILE],
        acc: &mut [f64],
    ) {
        let TileGrad { values: gt, finite } = grad;
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
pub(super) fn block(v: &[f32], o: usize) -> &[f32; HALF] {
    v[o..o + HALF].try_into().expect("HALF-wide block")
}

/// The mutable `HALF`-lane block of `v` at offset `o`.
#[inline(always)]
pub(super) fn block_mut(v: &mut [f32], o: usize) -> &mut [f32; HALF] {
    (&mut v[o..o + HALF]).try_into().expect("HALF-wide block")
}

/// Visit the pixels of an exact splat inside tile rect `r`: `f(local_index, col, row)`.
#[inline(always)]
pub(super) fn exact_pixels(
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
