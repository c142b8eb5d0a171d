//! The per-view preparation of every Gaussian: affine pixel splats (f32, also the prepared
//! state the Burn ops keep between forward and backward) or exact splats (f64), with their
//! pixel boxes.

use super::*;

/// An affine splat reduced to what the pixel loop reads (f32), with its clamped pixel box.
#[derive(Clone, Copy, Debug)]
pub(super) struct PixelSplat {
    pub(super) mx: f32,
    pub(super) my: f32,
    pub(super) a: f32,
    pub(super) beta: f32,
    pub(super) gamma: f32,
    /// Integration factor μ (length units), so a pass reads one array per Gaussian.
    pub(super) mu: f32,
    /// Pixel box `[x0, x1) × [y0, y1)` clamped to the detector.
    pub(super) x0: u32,
    pub(super) x1: u32,
    pub(super) y0: u32,
    pub(super) y1: u32,
}

/// Width of one Gaussian's affine record in a prepared-state buffer (see [`project_prepare`]).
pub const PREPARED_WIDTH: usize = 10;

/// Width of one Gaussian's record in this backend's prepared state for `mode`: the affine
/// [`PixelSplat`] record, or nothing (exact mode prepares in f64 inside each pass).
pub fn prepared_width(mode: ProjectionMode) -> usize {
    match mode {
        ProjectionMode::Affine => PREPARED_WIDTH,
        ProjectionMode::Exact => 0,
    }
}

impl PixelSplat {
    /// `[mx, my, a, β, γ, μ, x0, x1, y0, y1]`; a culled Gaussian is all zeros (an empty box).
    /// Box bounds are below 2²⁰ (the detector limit), so exact in f32.
    pub(super) fn pack(s: Option<&PixelSplat>) -> [f32; PREPARED_WIDTH] {
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
    /// another detector cannot index outside this one); `None` if culled.
    pub(super) fn unpack(v: &[f32], det: &Detector) -> Option<PixelSplat> {
        let [x0, x1, y0, y1] = Self::unpack_box(v, det)?;
        Some(PixelSplat {
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
        })
    }

    /// The clamped pixel box `[x0, x1, y0, y1]` of a packed record, `None` if it is empty.
    #[inline(always)]
    fn unpack_box(v: &[f32], det: &Detector) -> Option<[usize; 4]> {
        // `as` saturates (NaN → 0), so the clamped box is always a valid index range.
        let x0 = v[6] as usize;
        let x1 = (v[7] as usize).min(det.cols);
        let y0 = v[8] as usize;
        let y1 = (v[9] as usize).min(det.rows);
        (x0 < x1 && y0 < y1).then_some([x0, x1, y0, y1])
    }

    /// Its rows `[y0, y1)`.
    pub(super) fn rows(&self) -> std::ops::Range<usize> {
        self.y0 as usize..self.y1 as usize
    }
}

pub(super) struct Detector {
    pub(super) rows: usize,
    pub(super) cols: usize,
}

impl Detector {
    pub(super) fn new(cam: &Camera) -> Self {
        Self {
            rows: cam.rows,
            cols: cam.cols,
        }
    }

    /// Pixel box `[x0, x1, y0, y1]` (ends exclusive) of a footprint `[col_min, col_max] ×
    /// [row_min, row_max]`, clamped to the detector; `None` if it misses it.
    pub(super) fn pixel_box(&self, bb: [f64; 4]) -> Option<[usize; 4]> {
        let (x0, x1, _, _) = tile_span(bb[0], bb[1], self.cols, 1)?;
        let (y0, y1, _, _) = tile_span(bb[2], bb[3], self.rows, 1)?;
        Some([x0, x1, y0, y1])
    }
}

/// Per-view preparation of every Gaussian.
pub(super) enum Prepared<'a> {
    /// Pixel splats (the chain rule recomputes the f64 splat it needs).
    Affine(AffineSplats<'a>),
    Exact(Vec<Option<(ExactSplat, [usize; 4])>>),
}

/// The affine pixel splats of one view: read from a prepared state as they are used (one
/// record per Gaussian, no unpacked copy), or computed.
pub(super) enum AffineSplats<'a> {
    Packed { records: &'a [f32], det: Detector },
    Computed(Vec<Option<PixelSplat>>),
}

impl AffineSplats<'_> {
    /// Gaussian `i`'s splat, `None` if it is culled.
    #[inline(always)]
    pub(super) fn get(&self, i: usize) -> Option<PixelSplat> {
        match self {
            Self::Packed { records, det } => {
                PixelSplat::unpack(&records[i * PREPARED_WIDTH..(i + 1) * PREPARED_WIDTH], det)
            }
            Self::Computed(s) => s[i],
        }
    }

    /// Every Gaussian's splat, in index order.
    pub(super) fn iter(&self) -> impl Iterator<Item = Option<PixelSplat>> + '_ {
        let n = match self {
            Self::Packed { records, .. } => records.len() / PREPARED_WIDTH,
            Self::Computed(s) => s.len(),
        };
        (0..n).map(|i| self.get(i))
    }
}

pub(super) fn screen_offset(screen: &[f32], k: usize, view: usize, i: usize) -> [f64; 2] {
    let o = 2 * (view * k + i);
    [screen[o] as f64, screen[o + 1] as f64]
}

/// What the per-Gaussian preparation of one view reads: the Gaussians, the per-view screen
/// offsets, the view's index and camera, and the projection's options.
#[derive(Clone, Copy)]
pub(super) struct ViewInputs<'a> {
    pub(super) g: &'a GaussianSlices<'a>,
    pub(super) screen: &'a [f32],
    pub(super) view: usize,
    pub(super) cam: &'a Camera,
    pub(super) opts: &'a ProjectOptions,
}

impl ViewInputs<'_> {
    /// Gaussian `i`'s screen offset in this view.
    pub(super) fn offset(&self, i: usize) -> [f64; 2] {
        screen_offset(self.screen, self.g.len(), self.view, i)
    }

    /// The near plane's distance from the source.
    pub(super) fn near(&self) -> f64 {
        self.opts.near_fraction * self.cam.sdd
    }
}

dispatched! {
    /// The affine pixel splats (f32) of Gaussians `first..first + out.len()` (at most
    /// [`F64_LANES`]) in the view, prepared together in f64 lanes; `None` for one that is
    /// culled (non-finite density, degenerate, behind the near plane, off the detector).
    pub(super) fn affine_splats(view: ViewInputs<'_>, first: usize, out: &mut [Option<PixelSplat>]) {
        // Lanes past the end repeat the group's last Gaussian; their results are not used.
        let last = first + out.len() - 1;
        let at = |j: usize| (first + j).min(last);
        let geom = GaussianGeom::lanes(|j| view.g.geom(at(j)));
        let offsets = F64x4::gather(|j| view.offset(at(j)));
        let (splats, ok) =
            gm::splat_masked(&geom, view.cam, offsets, view.opts.cutoff, view.near());
        let det = Detector::new(view.cam);
        for (j, o) in out.iter_mut().enumerate() {
            *o = (ok.lane(j) && view.g.densities_of(first + j).is_some())
                .then(|| pixel_splat(&splats.lane(j), &det))
                .flatten();
        }
    }
}

/// The f32 pixel splat of `s` with its pixel box, or `None` if it misses the detector or does
/// not fit f32.
fn pixel_splat(s: &gm::Splat, det: &Detector) -> Option<PixelSplat> {
    let bb = [
        s.mean[0] - s.half_extent[0],
        s.mean[0] + s.half_extent[0],
        s.mean[1] - s.half_extent[1],
        s.mean[1] + s.half_extent[1],
    ];
    let px = det.pixel_box(bb)?;
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
    (ps.a.is_finite() && ps.beta.is_finite() && ps.gamma.is_finite()).then_some(ps)
}

/// Prepared state of every view and Gaussian, `[V, K, PREPARED_WIDTH]` (f32): the affine pixel
/// splats ([`PixelSplat::pack`]) that [`project_forward_prepared`] and
/// [`project_backward_prepared`] read instead of recomputing them, so one forward and its
/// backward prepare every Gaussian once. Exact mode keeps its f64 preparation internal (f32
/// would lose the per-ray accuracy it exists for): its prepared state is empty.
pub fn project_prepare(
    g: &GaussianSlices,
    screen: &[f32],
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    let k = g.len();
    let mut out = zeros(cams.len() * k * prepared_width(opts.mode));
    if out.is_empty() {
        return out;
    }
    for (v, cam) in cams.iter().enumerate() {
        let inputs = ViewInputs {
            g,
            screen,
            view: v,
            cam,
            opts,
        };
        out[v * k * PREPARED_WIDTH..(v + 1) * k * PREPARED_WIDTH]
            .par_chunks_mut(F64_LANES * PREPARED_WIDTH)
            .enumerate()
            .with_min_len(16)
            .for_each(|(c, recs)| {
                let mut splats = [None; F64_LANES];
                let splats = &mut splats[..recs.len() / PREPARED_WIDTH];
                affine_splats(inputs, c * F64_LANES, splats);
                for (rec, s) in recs.chunks_exact_mut(PREPARED_WIDTH).zip(splats.iter()) {
                    rec.copy_from_slice(&PixelSplat::pack(s.as_ref()));
                }
            });
    }
    out
}

/// The preparation of `view`: unpacked from `prepared` (affine, see [`project_prepare`]) or
/// computed (exact, or affine without a prepared state).
pub(super) fn prepare<'a>(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: Option<&'a [f32]>,
    view: usize,
    cam: &Camera,
    opts: &ProjectOptions,
) -> Prepared<'a> {
    let k = g.len();
    let det = Detector::new(cam);
    match opts.mode {
        ProjectionMode::Affine => Prepared::Affine(match prepared {
            Some(p) => AffineSplats::Packed {
                records: &p[view * k * PREPARED_WIDTH..(view + 1) * k * PREPARED_WIDTH],
                det,
            },
            None => {
                let inputs = ViewInputs {
                    g,
                    screen,
                    view,
                    cam,
                    opts,
                };
                let mut splats = vec![None; k];
                splats
                    .par_chunks_mut(F64_LANES)
                    .enumerate()
                    .with_min_len(16)
                    .for_each(|(c, out)| affine_splats(inputs, c * F64_LANES, out));
                AffineSplats::Computed(splats)
            }
        }),
        ProjectionMode::Exact => Prepared::Exact(
            (0..k)
                .into_par_iter()
                .map(|i| {
                    g.densities_of(i)?;
                    let off = screen_offset(screen, k, view, i);
                    let s = exact_splat(&g.geom(i), cam, off, opts.cutoff)?;
                    let px = det.pixel_box(s.bbox)?;
                    Some((s, px))
                })
                .collect(),
        ),
    }
}
