//! Ellipsoids: exact chord length along a ray segment and point membership.
//!
//! An ellipsoid has a centre `c` (mm), semi-axes `(a, b, c)` (mm) along its own body axes, and an
//! orientation given by ZYZ Euler angles `rotation_deg = [φ, θ, ψ]` (degrees):
//! `R = Rz(φ)·Ry(θ)·Rz(ψ)`, whose columns are the body axes in world coordinates. A world point
//! `p` has body coordinates `q = Rᵀ(p − c)` and lies inside when `Σ (qᵢ/aᵢ)² ≤ 1`. With only `φ`
//! non-zero the ellipsoid is turned counter-clockwise about +z (from x towards y), the rotation
//! of the 2D Shepp–Logan tables.

use crate::Result;
use crate::error::{ensure_finite, ensure_positive};
use crate::geometry::{dot, sub};
use prism_camera::Ray;
use serde::{Deserialize, Serialize};

/// An ellipsoid in world coordinates (mm); see the module docs for the rotation convention.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ellipsoid {
    /// Centre (x, y, z), mm.
    pub centre: [f64; 3],
    /// Semi-axes along the body axes, mm.
    pub semi_axes: [f64; 3],
    /// ZYZ Euler angles [φ, θ, ψ], degrees: `R = Rz(φ)·Ry(θ)·Rz(ψ)`.
    #[serde(default)]
    pub rotation_deg: [f64; 3],
}

impl Ellipsoid {
    /// An axis-aligned ellipsoid.
    pub fn axis_aligned(centre: [f64; 3], semi_axes: [f64; 3]) -> Self {
        Ellipsoid {
            centre,
            semi_axes,
            rotation_deg: [0.0; 3],
        }
    }

    /// A sphere of radius `r`.
    pub fn sphere(centre: [f64; 3], r: f64) -> Self {
        Self::axis_aligned(centre, [r; 3])
    }

    /// Check that every number is finite and the semi-axes are positive.
    pub fn validate(&self) -> Result<()> {
        for k in 0..3 {
            ensure_finite(format!("centre[{k}]"), self.centre[k])?;
            ensure_positive(format!("semi_axes[{k}]"), self.semi_axes[k])?;
            ensure_finite(format!("rotation_deg[{k}]"), self.rotation_deg[k])?;
        }
        Ok(())
    }

    /// Rotation matrix `R = Rz(φ)·Ry(θ)·Rz(ψ)`; its columns are the body axes in world coordinates.
    pub fn rotation(&self) -> [[f64; 3]; 3] {
        let [phi, theta, psi] = self.rotation_deg.map(f64::to_radians);
        matmul(matmul(rot_z(phi), rot_y(theta)), rot_z(psi))
    }

    /// Body coordinates scaled to the unit sphere: `M·(p − c)` with `M = diag(1/aᵢ)·Rᵀ`.
    pub(crate) fn unit_map(&self) -> UnitMap {
        let r = self.rotation();
        let mut m = [[0.0; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = r[j][i] / self.semi_axes[i];
            }
        }
        UnitMap {
            centre: self.centre,
            m,
        }
    }

    /// `Σ (qᵢ/aᵢ)²` of world point `p`: ≤ 1 inside, > 1 outside.
    pub fn level(&self, p: [f64; 3]) -> f64 {
        self.unit_map().level(p)
    }

    /// True when `p` lies inside or on the surface.
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.level(p) <= 1.0
    }

    /// Exact length (mm) of the part of the segment `origin + t·direction`, `t ∈ [0, length]`, that
    /// lies inside; `direction` must be a unit vector.
    pub fn chord(&self, origin: [f64; 3], direction: [f64; 3], length: f64) -> f64 {
        self.unit_map().chord(origin, direction, length)
    }

    /// Exact length (mm) of `ray` inside the ellipsoid.
    pub fn ray_chord(&self, ray: &Ray) -> f64 {
        self.chord(ray.origin, ray.direction, ray.length)
    }

    /// Axis-aligned bounding box (min, max corners), mm: the half-extent along world axis i is
    /// `√(Σⱼ (Rᵢⱼ aⱼ)²)`.
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        let r = self.rotation();
        let mut lo = [0.0; 3];
        let mut hi = [0.0; 3];
        for i in 0..3 {
            let h = (0..3)
                .map(|j| (r[i][j] * self.semi_axes[j]).powi(2))
                .sum::<f64>()
                .sqrt();
            lo[i] = self.centre[i] - h;
            hi[i] = self.centre[i] + h;
        }
        (lo, hi)
    }
}

/// The affine map of an ellipsoid onto the unit sphere, precomputed for repeated queries.
#[derive(Clone, Copy, Debug)]
pub(crate) struct UnitMap {
    centre: [f64; 3],
    m: [[f64; 3]; 3],
}

impl UnitMap {
    fn apply(&self, v: [f64; 3]) -> [f64; 3] {
        let m = &self.m;
        [
            m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
            m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
            m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
        ]
    }

    pub(crate) fn level(&self, p: [f64; 3]) -> f64 {
        let q = self.apply(sub(p, self.centre));
        dot(q, q)
    }

    /// Chord of the segment `s + t·d`, `t ∈ [0, l]`. In unit-sphere coordinates the ray is
    /// `s' + t·d'`; with `α = d'·d'` the closest approach to the centre is at `t* = −s'·d'/α`, at
    /// squared distance `ρ² = |s' + t* d'|²`, and the ray is inside for `|t − t*| ≤ h`,
    /// `h = √((1 − ρ²)/α)`. This equals the textbook `t± = (−β ± √(β² − αγ))/α` but evaluates
    /// `1 − ρ²` without the cancellation of `β² − αγ` for distant sources.
    pub(crate) fn chord(&self, s: [f64; 3], d: [f64; 3], l: f64) -> f64 {
        if l.is_nan() || l <= 0.0 {
            return 0.0;
        }
        let sp = self.apply(sub(s, self.centre));
        let dp = self.apply(d);
        let alpha = dot(dp, dp);
        if !alpha.is_finite() || alpha <= 0.0 {
            return 0.0;
        }
        let t_star = -dot(sp, dp) / alpha;
        let closest = [
            sp[0] + t_star * dp[0],
            sp[1] + t_star * dp[1],
            sp[2] + t_star * dp[2],
        ];
        let rest = 1.0 - dot(closest, closest);
        if rest.is_nan() || rest <= 0.0 {
            return 0.0;
        }
        let h = (rest / alpha).sqrt();
        let (t0, t1) = (t_star - h, t_star + h);
        if t0 >= 0.0 && t1 <= l {
            // The whole chord lies on the segment: 2h is exact and free of the rounding of t*.
            2.0 * h
        } else {
            (t1.min(l) - t0.max(0.0)).max(0.0)
        }
    }
}

fn rot_z(a: f64) -> [[f64; 3]; 3] {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

fn rot_y(a: f64) -> [[f64; 3]; 3] {
    let (s, c) = a.sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

fn matmul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests;
