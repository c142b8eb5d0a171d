//! Seeded per-view deviations from the circular orbit (`geometry.disturb` of a simulate config):
//! what an uncalibrated or wobbling scanner does. The simulated scene stores every view's true
//! pose as per-view vectors (`docs/geometry.md`, "Per-view vectors"), its circular fields
//! unchanged as the nominal scan, so a method can be run with the true poses or, with the
//! `vectors` block removed from `scene.yaml`, with the nominal ones.

use crate::geometry::{Beam, Geometry, ViewVectors, cross, rotate, unit};
use crate::{Error, Result};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// Standard deviations of independent per-view deviations (each view draws its own).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisturbSpec {
    /// Source position, each world axis, mm (cone beam).
    #[serde(default)]
    pub source_mm: f64,
    /// Detector centre within its plane, along u and along v, mm.
    #[serde(default)]
    pub detector_mm: f64,
    /// Detector turned within its plane, degrees.
    #[serde(default)]
    pub spin_deg: f64,
    /// Detector tilted out of its plane, about its rows and about its columns, degrees (cone
    /// beam).
    #[serde(default)]
    pub tilt_deg: f64,
}

impl DisturbSpec {
    /// Every σ finite and ≥ 0; a parallel beam takes only `detector_mm` and `spin_deg` (its
    /// rays have no source, and a detector tilted against them would have skewed pixels).
    pub fn validate(&self, beam: Beam) -> Result<()> {
        for (field, v) in [
            ("source_mm", self.source_mm),
            ("detector_mm", self.detector_mm),
            ("spin_deg", self.spin_deg),
            ("tilt_deg", self.tilt_deg),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(
                    field,
                    format!("a standard deviation: finite and ≥ 0, got {v}"),
                ));
            }
            if beam == Beam::Parallel && v > 0.0 && matches!(field, "source_mm" | "tilt_deg") {
                return Err(Error::invalid(
                    field,
                    "applies to cone beams only (parallel: detector_mm and spin_deg)",
                ));
            }
        }
        Ok(())
    }

    /// `g` (circular) with every view disturbed, drawn from `seed`.
    pub fn apply(&self, g: &Geometry, seed: u64) -> Result<Geometry> {
        self.validate(g.beam)?;
        // A stream of its own: the test angles keep theirs.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x0064_6973_7475_7262);
        let unit = Normal::new(0.0, 1.0).expect("σ = 1");
        let mut draw = |sigma: f64| sigma * unit.sample(&mut rng);
        let vectors = g
            .to_vectors()
            .into_iter()
            .map(|mut w| {
                if g.beam == Beam::Cone {
                    for k in 0..3 {
                        w.source[k] += draw(self.source_mm);
                    }
                }
                let (eu, ev) = (unit_of(w.u), unit_of(w.v));
                let (du, dv) = (draw(self.detector_mm), draw(self.detector_mm));
                for k in 0..3 {
                    w.detector[k] += du * eu[k] + dv * ev[k];
                }
                let normal = cross(eu, ev);
                let spin = draw(self.spin_deg).to_radians();
                w.u = rotate(w.u, normal, spin);
                w.v = rotate(w.v, normal, spin);
                if g.beam == Beam::Cone {
                    let (a, b) = (draw(self.tilt_deg), draw(self.tilt_deg));
                    let (eu, ev) = (unit_of(w.u), unit_of(w.v));
                    // About the rows (v's direction) and about the columns (u's).
                    let r = |x: [f64; 3]| rotate(rotate(x, ev, a.to_radians()), eu, b.to_radians());
                    w = ViewVectors {
                        u: r(w.u),
                        v: r(w.v),
                        ..w
                    };
                }
                w
            })
            .collect();
        let out = Geometry {
            vectors: Some(vectors),
            ..g.clone()
        };
        out.validate()?;
        Ok(out)
    }
}

fn unit_of(a: [f64; 3]) -> [f64; 3] {
    unit(a).expect("a detector axis has a length")
}
