//! Rotation-axis (centre-of-rotation) estimation from the projections themselves.
//!
//! Both estimators work on the central plane's sinogram ([`CentralSinogram`]): the mean of every
//! detector row for a parallel beam (each row is a parallel projection of its own slice, so the
//! mean projects the slab's mean), the row through the principal point for a cone or fan beam
//! (interpolated between the two nearest rows when it falls between them).
//!
//! * [`AxisMethod::Opposing`]: every ray is compared with its conjugate, the same line measured
//!   from the other side, interpolated (linearly in angle and column) from the views around it;
//!   the metric is the mean squared difference. The conjugate is found from the geometry's own
//!   cameras (parallel: θ + π at the mirrored column; fan: the ray's second crossing of the
//!   source circle, i.e. θ + π + 2γ), so no sign convention is restated here. Needs a full turn.
//! * [`AxisMethod::Sharpness`]: the central slice is filtered-backprojected (FDK/FBP with a Hann
//!   window) at each candidate and scored by the entropy of its histogram over the disc every
//!   view sees (Donath et al., J. Opt. Soc. Am. A 23 (2006) 1048); the histogram's range is fixed
//!   once, from the image at the given offset. Any angular range.
//!
//! The search: a coarse scan over the given offset ± `range_px` (every column for opposing
//! views; every other column on a slice coarsened to at most 160² voxels for sharpness, whose
//! basin is several columns wide), a fine scan at ¼ column over ±1.5 columns around its
//! minimum, and the vertex of the parabola through the fine minimum and its neighbours. The
//! uncertainty is the standard error over four disjoint view subsets (views `k ≡ j mod 4`),
//! each searched around the whole-scan estimate (± two coarse steps, then finely).

use super::fdk::fdk;
use super::filter::Window;
use crate::{Error, Result};
use ndarray::{Array2, Array3, Axis};
use prism_domain::geometry::{Beam, Geometry, VolumeGrid};
use prism_domain::import::{AxisConfig, AxisEstimate, AxisMethod};
use prism_domain::observe::Observer;
use prism_domain::scene::Scene;
use rayon::prelude::*;
use std::f64::consts::{PI, TAU};

/// View subsets behind the uncertainty.
const SUBSETS: usize = 4;
/// Histogram bins of the entropy.
const BINS: usize = 256;
/// The sharpness slices' sides, voxels: the coarse scan's and the refinement's.
const COARSE_SIDE: usize = 160;
/// The refinement: this many samples this far apart (columns), centred on the coarse minimum.
const FINE_SAMPLES: usize = 13;
const FINE_STEP: f64 = 0.25;
const FINE_SIDE: usize = 512;
/// A subset's search: the whole-scan estimate ± this many coarse steps, then refined.
const SUBSET_STEPS: usize = 2;

/// The sinogram of the plane z = 0 and a one-row geometry that holds it (a one-voxel slice).
#[derive(Clone, Debug)]
pub struct CentralSinogram {
    pub geometry: Geometry,
    /// `[views][cols]` line integrals.
    pub values: Array2<f32>,
    /// Which detector rows it came from, in words.
    pub rows: String,
}

impl CentralSinogram {
    /// The central sinogram of `scene`, from the channels measured at every view the estimate
    /// uses: all channels at all views, else the channel measured at the most views (its views).
    pub fn of(scene: &Scene) -> Result<CentralSinogram> {
        let g = &scene.geometry;
        if !g.is_circular() {
            return Err(Error::invalid(
                "geometry.vectors",
                "the axis search shifts a circular orbit's detector; per-view vectors already \
                 place every view (shift their detector centres instead)",
            ));
        }
        let (n, m) = (scene.n_views(), scene.n_channels());
        let count = |c: usize| (0..n).filter(|&v| scene.availability[[v, c]]).count();
        let best = (0..m).max_by_key(|&c| count(c)).unwrap_or(0);
        let views: Vec<usize> = (0..n).filter(|&v| scene.availability[[v, best]]).collect();
        let channels: Vec<usize> = (0..m)
            .filter(|&c| views.iter().all(|&v| scene.availability[[v, c]]))
            .collect();
        if views.len() < 2 * SUBSETS {
            return Err(Error::invalid(
                "axis",
                format!(
                    "{} views measured by one channel: too few to estimate the axis",
                    views.len()
                ),
            ));
        }
        let d = &g.detector;
        // Row weights: the plane z = 0 for cone beams, every row for parallel beams.
        let (weights, rows): (Vec<(usize, f64)>, String) = match g.beam {
            Beam::Parallel => (
                (0..d.rows).map(|r| (r, 1.0 / d.rows as f64)).collect(),
                format!("mean of the {} detector rows", d.rows),
            ),
            Beam::Cone => {
                let cy = g.camera(0).cy;
                if cy < 0.0 || cy > (d.rows - 1) as f64 {
                    return Err(Error::invalid(
                        "geometry.detector.offset_v",
                        "the plane z = 0 projects outside the detector rows",
                    ));
                }
                let lo = cy.floor() as usize;
                let f = cy - lo as f64;
                if f < 1e-9 || lo + 1 >= d.rows {
                    (vec![(lo, 1.0)], format!("row {lo}"))
                } else {
                    (
                        vec![(lo, 1.0 - f), (lo + 1, f)],
                        format!("rows {lo} and {} interpolated", lo + 1),
                    )
                }
            }
        };
        let mut values = Array2::<f32>::zeros((views.len(), d.cols));
        for &c in &channels {
            let p = scene.channel_projections(c);
            for (k, &v) in views.iter().enumerate() {
                for &(r, w) in &weights {
                    let line = p.slice(ndarray::s![v, r, ..]);
                    values
                        .row_mut(k)
                        .zip_mut_with(&line, |a, &b| *a += (w / channels.len() as f64) as f32 * b);
                }
            }
        }
        let mut one = g.with_views(&views);
        one.detector.rows = 1;
        one.detector.offset_v = 0.0;
        one.volume.nz = 1;
        one.volume.dz = match g.beam {
            Beam::Parallel => d.pitch_v,
            Beam::Cone => d.pitch_v * g.dso / g.dsd,
        };
        one.volume.offset[2] = 0.0;
        Ok(CentralSinogram {
            geometry: one,
            values,
            rows,
        })
    }

    fn views(&self) -> usize {
        self.values.nrows()
    }

    /// The geometry with the axis `offset_px` columns off (as `offset_u / pitch_u`).
    fn at(&self, offset_px: f64) -> Geometry {
        let mut g = self.geometry.clone();
        g.detector.offset_u = offset_px * g.detector.pitch_u;
        g
    }

    /// Whether the conjugate of (almost) every ray was measured: a full turn.
    pub fn full_turn(&self) -> bool {
        let ring = AngleRing::new(&self.geometry.angles_rad);
        let covered = self
            .geometry
            .angles_rad
            .iter()
            .filter(|&&a| ring.bracket(a + PI).is_some())
            .count();
        covered as f64 >= 0.9 * self.views() as f64
    }
}

/// The view angles sorted on the circle, to interpolate between the views around any angle.
struct AngleRing {
    /// (angle in [0, 2π), view index), sorted.
    sorted: Vec<(f64, usize)>,
    /// Gaps wider than this are not interpolated across (1.5× the median step).
    max_gap: f64,
}

impl AngleRing {
    fn new(angles: &[f64]) -> AngleRing {
        let mut sorted: Vec<(f64, usize)> = angles
            .iter()
            .enumerate()
            .map(|(k, a)| (a.rem_euclid(TAU), k))
            .collect();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = sorted.len();
        let mut gaps: Vec<f64> = (0..n)
            .map(|i| {
                let next = if i + 1 < n {
                    sorted[i + 1].0
                } else {
                    sorted[0].0 + TAU
                };
                next - sorted[i].0
            })
            .collect();
        gaps.sort_by(f64::total_cmp);
        let median = gaps.get(n / 2).copied().unwrap_or(TAU);
        AngleRing {
            sorted,
            max_gap: 1.5 * median,
        }
    }

    /// The two views around `angle` and the weight of the second, if they are close enough.
    fn bracket(&self, angle: f64) -> Option<(usize, usize, f64)> {
        let a = angle.rem_euclid(TAU);
        let n = self.sorted.len();
        let i = self.sorted.partition_point(|(x, _)| *x <= a);
        // The neighbours below and above `a`, across 0 where needed.
        let (lo_a, lo_v) = match i {
            0 => (self.sorted[n - 1].0 - TAU, self.sorted[n - 1].1),
            _ => self.sorted[i - 1],
        };
        let (hi_a, hi_v) = match i {
            _ if i == n => (self.sorted[0].0 + TAU, self.sorted[0].1),
            _ => self.sorted[i],
        };
        let gap = hi_a - lo_a;
        if gap > self.max_gap || gap <= 0.0 {
            return None;
        }
        Some((lo_v, hi_v, (a - lo_a) / gap))
    }
}

/// The estimator's score of candidate offsets (columns): lower is better.
pub trait AxisMetric {
    fn score(&self, offset_px: f64, subset: Option<usize>) -> Result<f64>;
}

/// Mean squared difference between rays and their conjugates.
pub struct Opposing<'a> {
    sino: &'a CentralSinogram,
    ring: AngleRing,
}

impl<'a> Opposing<'a> {
    pub fn new(sino: &'a CentralSinogram) -> Result<Opposing<'a>> {
        if !sino.full_turn() {
            return Err(Error::invalid(
                "axis.method",
                "`opposing` needs the conjugate rays measured (a full turn of views); use \
                 `sharpness`",
            ));
        }
        Ok(Opposing {
            sino,
            ring: AngleRing::new(&sino.geometry.angles_rad),
        })
    }
}

impl AxisMetric for Opposing<'_> {
    fn score(&self, offset_px: f64, subset: Option<usize>) -> Result<f64> {
        let g = self.sino.at(offset_px);
        let p = &self.sino.values;
        let cols = p.ncols();
        let (sum, count) = (0..self.sino.views())
            .into_par_iter()
            .filter(|k| subset.is_none_or(|j| k % SUBSETS == j))
            .map(|k| {
                let cam = g.camera(k);
                let theta = g.angles_rad[k];
                let mut acc = (0.0f64, 0usize);
                for i in 0..cols {
                    let ray = cam.pixel_ray(i as f64, cam.cy);
                    let (conj, point) = match g.beam {
                        Beam::Parallel => (theta + PI, ray.origin),
                        Beam::Cone => {
                            let (s, dir) = (ray.origin, ray.direction);
                            let t = -2.0 * (s[0] * dir[0] + s[1] * dir[1]);
                            let other = [s[0] + t * dir[0], s[1] + t * dir[1]];
                            (other[1].atan2(other[0]), s)
                        }
                    };
                    let Some(at) = g.camera_at(conj).project(point) else {
                        continue;
                    };
                    let col = at[0];
                    if !(0.0..=(cols - 1) as f64).contains(&col) {
                        continue;
                    }
                    let Some((v0, v1, w)) = self.ring.bracket(conj) else {
                        continue;
                    };
                    let c0 = (col.floor() as usize).min(cols - 2);
                    let f = col - c0 as f64;
                    let lerp = |v: usize| p[[v, c0]] as f64 * (1.0 - f) + p[[v, c0 + 1]] as f64 * f;
                    let q = lerp(v0) * (1.0 - w) + lerp(v1) * w;
                    let e = p[[k, i]] as f64 - q;
                    acc.0 += e * e;
                    acc.1 += 1;
                }
                acc
            })
            .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        if count == 0 {
            return Err(Error::invalid(
                "axis",
                format!("no ray has its conjugate on the detector at offset {offset_px} columns"),
            ));
        }
        Ok(sum / count as f64)
    }
}

/// Histogram entropy of the central slice's filtered backprojection.
pub struct Sharpness<'a> {
    sino: &'a CentralSinogram,
    /// The slice's grid: the scene's, coarsened to at most `side` voxels along x and y.
    grid: VolumeGrid,
    /// Voxels scored: inside the disc every view sees at the widest offset searched.
    mask: Vec<bool>,
    /// The histogram's fixed range.
    range: (f64, f64),
}

impl<'a> Sharpness<'a> {
    /// Scoring for offsets within `centre_px ± range_px`, on the scene's slice coarsened to at
    /// most `side` voxels along x and y (the same extent).
    pub fn new(
        sino: &'a CentralSinogram,
        centre_px: f64,
        range_px: f64,
        side: usize,
    ) -> Result<Sharpness<'a>> {
        let g = &sino.geometry;
        let d = &g.detector;
        let mut v = g.volume.clone();
        let factor = v.nx.max(v.ny).div_ceil(side.max(1)).max(1);
        if factor > 1 {
            v.nx = v.nx.div_ceil(factor);
            v.ny = v.ny.div_ceil(factor);
            v.dx = g.volume.dx * g.volume.nx as f64 / v.nx as f64;
            v.dy = g.volume.dy * g.volume.ny as f64 / v.ny as f64;
        }
        let magnification = match g.beam {
            Beam::Parallel => 1.0,
            Beam::Cone => g.dsd / g.dso,
        };
        // Half the detector at the isocentre, less the widest shift searched.
        let half = (d.cols as f64 / 2.0 - centre_px.abs() - range_px) * d.pitch_u / magnification;
        if half <= 0.0 {
            return Err(Error::invalid(
                "axis.range_px",
                format!(
                    "{range_px} columns around {centre_px}: no part of the slice is seen by every view"
                ),
            ));
        }
        let mask: Vec<bool> = (0..v.ny * v.nx)
            .map(|i| {
                let [x, y, _] = v.voxel_centre(i % v.nx, i / v.nx, 0);
                x * x + y * y < half * half
            })
            .collect();
        if mask.iter().filter(|&&m| m).count() < 100 {
            return Err(Error::invalid(
                "axis",
                "fewer than 100 voxels of the slice are seen by every view",
            ));
        }
        let mut s = Sharpness {
            sino,
            grid: v,
            mask,
            range: (0.0, 1.0),
        };
        let mut inside = s.inside(&s.slice(centre_px, None)?);
        inside.sort_by(f32::total_cmp);
        let pct = |q: f64| inside[((inside.len() - 1) as f64 * q) as usize] as f64;
        let (lo, hi) = (pct(0.01), pct(0.99));
        let width = (hi - lo).max(f64::MIN_POSITIVE);
        s.range = (lo - width, hi + width);
        Ok(s)
    }

    /// The slice at `offset_px` from every view, or from the views of one subset.
    pub fn slice(&self, offset_px: f64, subset: Option<usize>) -> Result<Array3<f32>> {
        let mut g = self.sino.at(offset_px);
        g.volume = self.grid.clone();
        let n = self.sino.views();
        let views: Vec<usize> = (0..n)
            .filter(|k| subset.is_none_or(|j| k % SUBSETS == j))
            .collect();
        let p = self
            .sino
            .values
            .select(Axis(0), &views)
            .insert_axis(Axis(1));
        fdk(&g.with_views(&views), p.view(), Window::Hann)
    }

    fn inside(&self, slice: &Array3<f32>) -> Vec<f32> {
        slice
            .iter()
            .zip(&self.mask)
            .filter(|(_, m)| **m)
            .map(|(v, _)| *v)
            .collect()
    }

    /// Entropy (nats) and the fraction of negative mass, `Σ max(−f, 0) / Σ |f|`, of a slice.
    pub fn scores(&self, slice: &Array3<f32>) -> (f64, f64) {
        let (lo, hi) = self.range;
        let mut hist = [0usize; BINS];
        let (mut neg, mut abs) = (0.0f64, 0.0f64);
        let inside = self.inside(slice);
        for &v in &inside {
            let v = v as f64;
            let b = ((v - lo) / (hi - lo) * BINS as f64).floor();
            hist[b.clamp(0.0, (BINS - 1) as f64) as usize] += 1;
            neg += (-v).max(0.0);
            abs += v.abs();
        }
        let total = inside.len() as f64;
        let entropy = hist
            .iter()
            .filter(|&&h| h > 0)
            .map(|&h| {
                let q = h as f64 / total;
                -q * q.ln()
            })
            .sum();
        (entropy, if abs > 0.0 { neg / abs } else { 0.0 })
    }
}

impl AxisMetric for Sharpness<'_> {
    fn score(&self, offset_px: f64, subset: Option<usize>) -> Result<f64> {
        Ok(self.scores(&self.slice(offset_px, subset)?).0)
    }
}

/// The sample offsets and scores of a search.
type Samples = Vec<(f64, f64)>;

/// The minimum of `coarse` over `centre ± half` at `step`, refined: `fine` scanned at
/// [`FINE_STEP`] around the coarse minimum and the vertex of the parabola through the fine
/// minimum's neighbours. Also whether the coarse minimum lies at the edge of the range.
fn minimise(
    coarse: &dyn AxisMetric,
    fine: &dyn AxisMetric,
    subset: Option<usize>,
    centre: f64,
    half: f64,
    step: f64,
    tick: &mut dyn FnMut(),
) -> Result<(f64, bool)> {
    let mut scan = |metric: &dyn AxisMetric, from: f64, n: usize, h: f64| -> Result<Samples> {
        (0..n)
            .map(|i| {
                let x = from + i as f64 * h;
                let y = metric.score(x, subset)?;
                tick();
                Ok((x, y))
            })
            .collect()
    };
    let n = (half / step).ceil() as usize;
    let rough = scan(coarse, centre - n as f64 * step, 2 * n + 1, step)?;
    let argmin = |s: &[(f64, f64)]| {
        (0..s.len())
            .min_by(|&a, &b| s[a].1.total_cmp(&s[b].1))
            .unwrap_or(0)
    };
    let m = argmin(&rough);
    let at_edge = n > 0 && (m == 0 || m == rough.len() - 1);
    let k = (FINE_SAMPLES / 2) as f64;
    let near = scan(fine, rough[m].0 - k * FINE_STEP, FINE_SAMPLES, FINE_STEP)?;
    let f = argmin(&near).clamp(1, near.len() - 2);
    let (y0, y1, y2) = (near[f - 1].1, near[f].1, near[f + 1].1);
    let curvature = y0 - 2.0 * y1 + y2;
    let shift = if curvature > 0.0 {
        (0.5 * (y0 - y2) / curvature).clamp(-1.0, 1.0)
    } else {
        0.0
    };
    Ok((near[f].0 + shift * FINE_STEP, at_edge))
}

/// The estimate of `config.method` for `scene`'s axis (its geometry's `offset_u` as the search
/// centre); a phase of `observer` counts the candidates scored.
pub fn estimate_axis(
    scene: &Scene,
    config: &AxisConfig,
    observer: &dyn Observer,
) -> Result<AxisEstimate> {
    let sino = CentralSinogram::of(scene)?;
    let d = &scene.geometry.detector;
    let given = d.offset_u;
    let centre = given / d.pitch_u;
    let range = config.range_for(d.cols);
    if !(range.is_finite() && range > 0.0) {
        return Err(Error::invalid(
            "axis.range_px",
            format!("must be finite and > 0, got {range}"),
        ));
    }
    let method = resolve(config.method, &sino);
    observer.phase(
        &format!("rotation axis by {}", method.describe()),
        estimate_steps(config, method, d.cols) as u64,
    );
    let mut done = 0;
    let tick = &mut || {
        done += 1;
        observer.progress(done, "");
    };
    // Sharpness scans coarsely on a coarse slice (the entropy's basin is several columns wide)
    // and refines on the scene's own; opposing views cost the same at every step.
    let (coarse, refined): (Box<dyn AxisMetric + '_>, Option<Box<dyn AxisMetric + '_>>) =
        match method {
            AxisMethod::Opposing => (Box::new(Opposing::new(&sino)?), None),
            _ => (
                Box::new(Sharpness::new(&sino, centre, range + 2.0, COARSE_SIDE)?),
                Some(Box::new(Sharpness::new(
                    &sino,
                    centre,
                    range + 2.0,
                    FINE_SIDE,
                )?)),
            ),
        };
    let (coarse, fine) = (
        coarse.as_ref(),
        refined.as_deref().unwrap_or(coarse.as_ref()),
    );
    let step = coarse_step(method);
    let (best, at_edge) = minimise(coarse, fine, None, centre, range, step, tick)?;
    if at_edge {
        return Err(Error::invalid(
            "axis.range_px",
            format!(
                "the best offset lies at the edge of the search ({centre:+.1} ± {range} columns): \
                 widen range_px or correct the geometry's offset_u"
            ),
        ));
    }
    let subsets = (0..SUBSETS)
        .map(|j| {
            let half = SUBSET_STEPS as f64 * step;
            minimise(fine, fine, Some(j), best, half, step, tick).map(|(x, _)| x)
        })
        .collect::<Result<Vec<f64>>>()?;
    let mean = subsets.iter().sum::<f64>() / SUBSETS as f64;
    let var = subsets.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (SUBSETS - 1) as f64;
    Ok(AxisEstimate {
        method,
        offset_u: best * d.pitch_u,
        offset_px: best,
        given_offset_u: given,
        uncertainty_px: (var / SUBSETS as f64).sqrt(),
        subsets,
        views: sino.views(),
        rows: sino.rows.clone(),
    })
}

/// `Auto` resolved for this sinogram (opposing on a full turn, else sharpness).
pub fn resolve(method: AxisMethod, sino: &CentralSinogram) -> AxisMethod {
    match method {
        AxisMethod::Auto | AxisMethod::Given if sino.full_turn() => AxisMethod::Opposing,
        AxisMethod::Auto | AxisMethod::Given => AxisMethod::Sharpness,
        m => m,
    }
}

/// The coarse scan's step, columns.
fn coarse_step(method: AxisMethod) -> f64 {
    match method {
        AxisMethod::Opposing => 1.0,
        _ => 2.0,
    }
}

/// How many candidates [`estimate_axis`] scores for a detector `cols` wide with `method`
/// (resolved).
fn estimate_steps(config: &AxisConfig, method: AxisMethod, cols: usize) -> usize {
    let n = (config.range_for(cols) / coarse_step(method)).ceil() as usize;
    (2 * n + 1) + FINE_SAMPLES + SUBSETS * (2 * SUBSET_STEPS + 1 + FINE_SAMPLES)
}
