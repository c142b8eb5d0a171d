//! The default scene's analytic spectral phantom (a torso-like slab of ellipsoids).

use super::ellipsoid::Ellipsoid;
use super::spectral::{CALCIUM_DENSITY_MG_ML, Component, SpectralPhantom, iodine_fraction};
use crate::Result;
use crate::physics::Material::{self, *};

/// One row of the built-in table: label, centre and semi-axes in units of the radius, rotation
/// about z (degrees), fraction deltas.
type Row = (
    &'static str,
    [f64; 3],
    [f64; 3],
    f64,
    &'static [(Material, f64)],
);

/// Iodine vial concentrations of the built-in phantom, mg/mL.
pub const BUILTIN_IODINE_MG_ML: [f64; 3] = [2.0, 5.0, 10.0];
/// Calcium insert concentration of the built-in phantom, mg/mL.
pub const BUILTIN_CALCIUM_MG_ML: f64 = 100.0;

impl SpectralPhantom {
    /// The built-in phantom scaled to `radius_mm`; it lies inside the cylinder `√(x²+y²) ≤ 0.9·r`,
    /// `|z| ≤ 0.85·r` (every component is a finite ellipsoid).
    ///
    /// | component | centre / r | semi-axes / r | rot z | fraction deltas |
    /// |---|---|---|---|---|
    /// | body (fat layer) | 0, 0, 0 | 0.90, 0.70, 0.85 | | adipose +1 |
    /// | body (water) | 0, 0, 0 | 0.84, 0.64, 0.80 | | adipose −1, water +1 |
    /// | liver | −0.40, 0.15, 0.05 | 0.25, 0.20, 0.40 | 20° | water −1, soft_tissue +1 |
    /// | visceral fat | −0.10, −0.15, −0.30 | 0.10, 0.06, 0.12 | | water −1, adipose +1 |
    /// | vertebra | 0, −0.40, 0 | 0.13, 0.11, 0.50 | | water −1, cortical_bone +1 |
    /// | marrow | 0, −0.40, 0 | 0.09, 0.07, 0.46 | | cortical_bone −0.7, water +0.7 |
    /// | rib left / right | ∓0.68, −0.15, 0 | 0.04, 0.05, 0.40 | | water −1, cortical_bone +1 |
    /// | iodine 2 / 5 / 10 mg/mL | (0.15, 0.35), (0.40, 0.20), (0.45, −0.10), z 0 | 0.08, 0.08, 0.30 | | iodine +c/4930 |
    /// | calcium 100 mg/mL | 0.15, −0.05, 0 | 0.07, 0.07, 0.25 | | calcium +100/1550 |
    /// | air pocket | −0.15, −0.15, 0 | 0.08, 0.06, 0.10 | | water −1, air +1 |
    ///
    /// Iodine and calcium fractions are volume fractions of the pure elements at their NIST
    /// densities (4.93 and 1.55 g/cm³); the water they displace (≤ 7 %) is neglected, as in
    /// commercial calibration phantoms' nominal values. Iodine (K-edge 33.2 keV) and bone
    /// contrast fall steeply from 40 to 100 keV while water/soft tissue/fat change little, so the
    /// energy channels differ visibly. Contrast over water, `Δμ/μ_water`, from the NIST table
    /// (`shared/data/nist/mu_over_rho.csv`):
    ///
    /// | insert | 40 keV | 70 keV | 100 keV |
    /// |---|---|---|---|
    /// | iodine 2 / 5 / 10 mg/mL | 16 / 41 / 82 % | 5 / 13 / 26 % | 2 / 6 / 11 % |
    /// | calcium 100 mg/mL | 68 % | 24 % | 15 % |
    /// | cortical bone | 376 % | 156 % | 109 % |
    /// | soft tissue / adipose | +6 / −15 % | +5 / −8 % | +5 / −6 % |
    pub fn builtin(radius_mm: f64) -> Result<SpectralPhantom> {
        crate::error::ensure_positive("radius_mm", radius_mm)?;
        let [i2, i5, i10] = BUILTIN_IODINE_MG_ML.map(iodine_fraction);
        let ca = BUILTIN_CALCIUM_MG_ML / CALCIUM_DENSITY_MG_ML;
        let rows: Vec<Row> = vec![
            (
                "body fat layer",
                [0.0, 0.0, 0.0],
                [0.90, 0.70, 0.85],
                0.0,
                &[(Adipose, 1.0)],
            ),
            (
                "body water",
                [0.0, 0.0, 0.0],
                [0.84, 0.64, 0.80],
                0.0,
                &[(Adipose, -1.0), (Water, 1.0)],
            ),
            (
                "liver",
                [-0.40, 0.15, 0.05],
                [0.25, 0.20, 0.40],
                20.0,
                &[(Water, -1.0), (SoftTissue, 1.0)],
            ),
            (
                "visceral fat",
                [-0.10, -0.15, -0.30],
                [0.10, 0.06, 0.12],
                0.0,
                &[(Water, -1.0), (Adipose, 1.0)],
            ),
            (
                "vertebra",
                [0.0, -0.40, 0.0],
                [0.13, 0.11, 0.50],
                0.0,
                &[(Water, -1.0), (CorticalBone, 1.0)],
            ),
            (
                "marrow",
                [0.0, -0.40, 0.0],
                [0.09, 0.07, 0.46],
                0.0,
                &[(CorticalBone, -0.7), (Water, 0.7)],
            ),
            (
                "rib left",
                [-0.68, -0.15, 0.0],
                [0.04, 0.05, 0.40],
                0.0,
                &[(Water, -1.0), (CorticalBone, 1.0)],
            ),
            (
                "rib right",
                [0.68, -0.15, 0.0],
                [0.04, 0.05, 0.40],
                0.0,
                &[(Water, -1.0), (CorticalBone, 1.0)],
            ),
            (
                "air pocket",
                [-0.15, -0.15, 0.0],
                [0.08, 0.06, 0.10],
                0.0,
                &[(Water, -1.0), (Air, 1.0)],
            ),
        ];
        let s = |v: [f64; 3]| v.map(|x| x * radius_mm);
        let mut ellipsoids: Vec<Component> = rows
            .into_iter()
            .map(|(label, c, a, rot, m)| {
                Component::new(
                    label,
                    Ellipsoid {
                        centre: s(c),
                        semi_axes: s(a),
                        rotation_deg: [rot, 0.0, 0.0],
                    },
                    m,
                )
            })
            .collect();
        let vials = [
            ("iodine 2 mg/mL", [0.15, 0.35, 0.0], i2),
            ("iodine 5 mg/mL", [0.40, 0.20, 0.0], i5),
            ("iodine 10 mg/mL", [0.45, -0.10, 0.0], i10),
        ];
        for (label, c, f) in vials {
            ellipsoids.push(Component::new(
                label,
                Ellipsoid::axis_aligned(s(c), s([0.08, 0.08, 0.30])),
                &[(Iodine, f)],
            ));
        }
        ellipsoids.push(Component::new(
            "calcium 100 mg/mL",
            Ellipsoid::axis_aligned(s([0.15, -0.05, 0.0]), s([0.07, 0.07, 0.25])),
            &[(Calcium, ca)],
        ));
        Ok(SpectralPhantom { ellipsoids })
    }
}
