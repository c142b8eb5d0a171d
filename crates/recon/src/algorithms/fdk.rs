//! FDK (cone beam) and FBP (parallel beam) filtered backprojection.
//!
//! For cone beam (Feldkamp, Davis & Kress 1984; Kak & Slaney §3.4.2 extended to 3-D):
//!
//! `f(x) ≈ Σ_k Δβ_k · r · (1/U_k²) · [ (c · p_k) ⊛ h ](u_k(x), v_k(x)) / τ`
//!
//! * `c(u, v) = DSD / √(DSD² + u² + v²)` is the cosine pre-weight, `(u, v)` the pixel position
//!   relative to the principal point (so detector offsets are honoured);
//! * `h` the ramp kernel in pixel units along detector rows ([`RampFilter`]) and `τ = pitch_u ·
//!   DSO / DSD` the pitch at the isocentre (`pitch_u` for parallel beam);
//! * with per-view vectors, the cosine weight, `τ` and `U` are each view's own (its camera's
//!   principal point, distances and pitches) and the backprojection follows each view's pose;
//!   `Δβ` and Parker's weights use the nominal angles. This is exact on a circular orbit and the
//!   usual approximation (as RTK's per-projection FDK) for wobble, tilts and shifts: the ramp
//!   still filters along detector rows.
//! * `U = (DSO − ⟨x, ŝ⟩)/DSO` (the voxel-driven [`backproject_voxel`]);
//! * `Δβ_k` the angular width each view stands for (half the gap to its neighbours, circularly for
//!   a full scan), and `r` the redundancy factor: ½ for a full scan (every ray is measured twice),
//!   or Parker weights for a short scan (each ray's two measurements weighted to sum to 1).
//!
//! A scan is *short* when its angular range plus 1.5 times its largest step is below 2π; a
//! sparse full turn (`n` views over 2π, endpoint excluded) is therefore never a short scan.
//! Parallel beam (FBP) uses angles modulo π with the same half-gap rule and no cosine weight.

use super::filter::{RampFilter, Window};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3};
use prism_domain::geometry::{Beam, Geometry};
use prism_domain::projector::backproject_voxel;
use rayon::prelude::*;
use std::f64::consts::PI;

/// How FDK handles redundancy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanKind {
    /// Full turn: every ray measured twice, weight ½.
    Full,
    /// Short scan (less than a turn): Parker weights.
    Short,
    /// Parallel beam: angles taken modulo π.
    Parallel,
}

/// Filtered backprojection with `window`; returns the volume (μ, mm⁻¹) on the geometry's grid.
///
/// `projections` is `[view][row][col]` for every view of `geometry`.
pub fn fdk(
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    window: Window,
) -> Result<Array3<f32>> {
    geometry.validate()?;
    let d = &geometry.detector;
    let want = [geometry.views(), d.rows, d.cols];
    prism_domain::error::ensure_shape(
        "projections",
        projections.shape(),
        &want,
        "[views, rows, cols]",
    )?;
    let kind = scan_kind(geometry);
    let mut p = projections.to_owned();
    let frames: Vec<ViewFrame> = (0..geometry.views())
        .map(|k| ViewFrame::of(geometry, k))
        .collect();
    // Pre-weights: cosine (cone; one image for every view on a circular orbit, where the
    // principal point is shared) and Parker (short scan).
    if geometry.beam == Beam::Cone {
        let parker = if kind == ScanKind::Short {
            Some(Parker::new(geometry)?)
        } else {
            None
        };
        let shared = geometry
            .is_circular()
            .then(|| frames[0].cosine(d.rows, d.cols));
        p.as_slice_mut()
            .expect("fresh array")
            .par_chunks_mut(d.rows * d.cols)
            .enumerate()
            .for_each(|(k, view)| {
                let f = &frames[k];
                let own;
                let cosine = match &shared {
                    Some(c) => c,
                    None => {
                        own = f.cosine(d.rows, d.cols);
                        &own
                    }
                };
                match &parker {
                    None => view.iter_mut().zip(cosine).for_each(|(x, c)| *x *= c),
                    Some(pk) => {
                        let w: Vec<f32> = (0..d.cols)
                            .map(|c| pk.weight(k, f.at(c, 0).0, f.dsd) as f32)
                            .collect();
                        for (line, cos) in view.chunks_mut(d.cols).zip(cosine.chunks(d.cols)) {
                            for ((x, c), w) in line.iter_mut().zip(cos).zip(&w) {
                                *x *= c * w;
                            }
                        }
                    }
                }
            });
    }
    RampFilter::new(d.cols, window)?.apply(&mut p)?;
    let redundancy = match kind {
        ScanKind::Full => 0.5,
        ScanKind::Short | ScanKind::Parallel => 1.0,
    };
    let scale: Vec<f64> = angular_weights(geometry, kind)
        .into_iter()
        .zip(&frames)
        .map(|(db, f)| db * redundancy / f.tau)
        .collect();
    let views: Vec<usize> = (0..geometry.views()).collect();
    Ok(backproject_voxel(geometry, p.view(), &views, &scale)?)
}

/// What the weights need of one view's detector: its principal point (pixels), pitches and
/// source–detector distance (mm) and its pitch at the isocentre `τ`. On a circular orbit every
/// view has the geometry's; with per-view vectors each has its own camera's.
struct ViewFrame {
    cx: f64,
    cy: f64,
    pitch_u: f64,
    pitch_v: f64,
    dsd: f64,
    tau: f64,
}

impl ViewFrame {
    fn of(geometry: &Geometry, view: usize) -> ViewFrame {
        let cam = geometry.camera(view);
        let d = &geometry.detector;
        match (&geometry.vectors, geometry.beam) {
            (None, _) => ViewFrame {
                cx: cam.cx,
                cy: cam.cy,
                pitch_u: d.pitch_u,
                pitch_v: d.pitch_v,
                dsd: geometry.dsd,
                tau: d.pitch_u / geometry.magnification(),
            },
            (Some(_), Beam::Cone) => {
                let pitch_u = cam.sdd / cam.fx;
                ViewFrame {
                    cx: cam.cx,
                    cy: cam.cy,
                    pitch_u,
                    pitch_v: cam.sdd / cam.fy,
                    dsd: cam.sdd,
                    // The isocentre's depth along the view axis over the detector's.
                    tau: pitch_u / (cam.sdd / cam.translation[2]),
                }
            }
            (Some(_), Beam::Parallel) => ViewFrame {
                cx: cam.cx,
                cy: cam.cy,
                pitch_u: 1.0 / cam.fx,
                pitch_v: 1.0 / cam.fy,
                dsd: cam.sdd,
                tau: 1.0 / cam.fx,
            },
        }
    }

    /// Pixel (column, row) relative to the principal point, mm.
    fn at(&self, c: usize, r: usize) -> (f64, f64) {
        (
            (c as f64 - self.cx) * self.pitch_u,
            (r as f64 - self.cy) * self.pitch_v,
        )
    }

    /// The cone-beam cosine weight `DSD / √(DSD² + u² + v²)` of every pixel, row-major.
    fn cosine(&self, rows: usize, cols: usize) -> Vec<f32> {
        let dsd = self.dsd;
        (0..rows * cols)
            .map(|i| {
                let (u, v) = self.at(i % cols, i / cols);
                (dsd / (dsd * dsd + u * u + v * v).sqrt()) as f32
            })
            .collect()
    }
}

/// Classify the scan (see the module docs).
pub fn scan_kind(geometry: &Geometry) -> ScanKind {
    if geometry.beam == Beam::Parallel {
        return ScanKind::Parallel;
    }
    let mut a = geometry.angles_rad.clone();
    a.sort_by(f64::total_cmp);
    let range = a[a.len() - 1] - a[0];
    let max_step = a.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
    if a.len() > 1 && range + 1.5 * max_step < 2.0 * PI {
        ScanKind::Short
    } else {
        ScanKind::Full
    }
}

/// Angular width Δβ each view stands for, in view order.
fn angular_weights(geometry: &Geometry, kind: ScanKind) -> Vec<f64> {
    let n = geometry.views();
    if n == 1 {
        return vec![match kind {
            ScanKind::Full => 2.0 * PI,
            _ => PI,
        }];
    }
    let period = match kind {
        ScanKind::Full => 2.0 * PI,
        ScanKind::Parallel => PI,
        ScanKind::Short => f64::INFINITY,
    };
    let wrap = |a: f64| {
        if period.is_finite() {
            a.rem_euclid(period)
        } else {
            a
        }
    };
    let mut order: Vec<(f64, usize)> = geometry
        .angles_rad
        .iter()
        .enumerate()
        .map(|(k, &a)| (wrap(a), k))
        .collect();
    order.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut out = vec![0.0; n];
    for i in 0..n {
        let (a, k) = order[i];
        let prev = if i > 0 {
            a - order[i - 1].0
        } else if period.is_finite() {
            a + period - order[n - 1].0
        } else {
            0.0
        };
        let next = if i + 1 < n {
            order[i + 1].0 - a
        } else if period.is_finite() {
            order[0].0 + period - a
        } else {
            0.0
        };
        out[k] = 0.5 * (prev + next);
    }
    out
}

/// Parker weights for a short cone-beam scan (Parker 1982, with the over-scan δ taken from the
/// actual range, as in the generalised form of Wesarg et al. 2002 with q = 1).
struct Parker {
    /// β of each view (angle − smallest angle), radians.
    beta: Vec<f64>,
    /// Half over-scan δ = (range − π)/2.
    delta: f64,
}

impl Parker {
    fn new(geometry: &Geometry) -> Result<Self> {
        let min = geometry
            .angles_rad
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let max = geometry
            .angles_rad
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let delta = 0.5 * (max - min - PI);
        if delta <= 0.0 {
            return Err(Error::invalid(
                "angles_rad",
                format!(
                    "a short scan needs more than 180° plus the fan angle (covers {:.1}°)",
                    (max - min).to_degrees()
                ),
            ));
        }
        Ok(Parker {
            beta: geometry.angles_rad.iter().map(|a| a - min).collect(),
            delta,
        })
    }

    /// Weight of view `k` at detector position `u` (mm from the principal point) on a detector
    /// `dsd` from the source.
    fn weight(&self, k: usize, u: f64, dsd: f64) -> f64 {
        // Our fan angle atan(u/DSD) is positive towards +u; the conjugate of (β, γ) is then
        // (β + π − 2γ, −γ), so Parker's formula (conjugate at β + π + 2γ) takes γ = −atan(u/DSD).
        parker_weight(self.beta[k], -(u / dsd).atan(), self.delta)
    }
}

/// Parker's weight at source angle β ∈ [0, π + 2δ] and fan angle γ (Parker's sign).
fn parker_weight(beta: f64, gamma: f64, delta: f64) -> f64 {
    let s2 = |x: f64| x.sin().powi(2);
    if beta < 0.0 || beta > PI + 2.0 * delta {
        0.0
    } else if beta < 2.0 * (delta - gamma) {
        s2(PI / 4.0 * beta / (delta - gamma))
    } else if beta < PI - 2.0 * gamma {
        1.0
    } else if delta + gamma > 0.0 {
        s2(PI / 4.0 * (PI + 2.0 * delta - beta) / (delta + gamma))
    } else {
        0.0
    }
}

#[cfg(test)]
#[path = "fdk_tests.rs"]
mod tests;
