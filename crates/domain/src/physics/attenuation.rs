//! Mass and linear attenuation coefficients from the embedded NIST/xraydb table.
//!
//! The table (`crates/domain/data/nist_mu_over_rho.csv`) gives μ/ρ in cm²/g for every [`Material`]
//! on a 0.5 keV grid from 10 to 150 keV. Between grid points we interpolate **log–log**: on each
//! interval μ/ρ follows the power law through its two end points, `μ/ρ(E) = μ_i·(E/E_i)^k` with
//! `k = ln(μ_{i+1}/μ_i) / ln(E_{i+1}/E_i)`. The value is exact at grid points.
//!
//! **Absorption edges.** Away from edges μ/ρ decreases with energy; an interval on which it
//! increases holds an edge (here only the iodine K-edge, 33.169 keV, between the 33.0 and
//! 33.5 keV points). A power law across such an interval would smear the step into a ramp, so on
//! an edge interval we extrapolate the neighbouring intervals instead: below the edge energy the
//! power law of the interval below, from the edge energy on the power law of the interval above.
//! The result is a sharp step at the tabulated edge energy, continuous and monotone on each side.

use super::Material;
use crate::{Error, Result};
use std::sync::OnceLock;

/// The embedded table (attribution in its `#` header).
const TABLE_CSV: &str = include_str!("../../data/nist_mu_over_rho.csv");

/// Absorption edges inside the table's range, keV (Elam/xraydb edge energies).
/// Every increasing interval of the table must hold one of these (checked by a test).
pub const ABSORPTION_EDGES: &[(Material, &str, f64)] = &[(Material::Iodine, "I K", 33.1694)];

/// Lowest energy of the table, keV.
pub const TABLE_MIN_KEV: f64 = 10.0;
/// Highest energy of the table, keV.
pub const TABLE_MAX_KEV: f64 = 150.0;

/// One material's curve: grid energies (keV) and μ/ρ (cm²/g), plus edge intervals.
#[derive(Debug)]
struct Curve {
    energies: Vec<f64>,
    values: Vec<f64>,
    /// `(i, edge_kev)`: an edge lies in `(energies[i], energies[i + 1])`.
    edges: Vec<(usize, f64)>,
    /// Density from the table, g/cm³ (cross-checked against [`Material::density`]).
    density: f64,
}

/// Column name of a material in the CSV.
fn table_name(m: Material) -> &'static str {
    match m {
        Material::Water => "water",
        Material::Air => "air_dry",
        Material::SoftTissue => "soft_tissue_icru44",
        Material::CorticalBone => "cortical_bone_icru44",
        Material::Adipose => "adipose_icru44",
        Material::Iodine => "iodine",
        Material::Calcium => "calcium",
        Material::Aluminium => "aluminium",
        Material::Iron => "iron",
        Material::Titanium => "titanium",
    }
}

/// Parse the embedded CSV. Errors name the line; the embedded table is validated by tests, so
/// [`curves`] treats a failure as a build defect.
fn parse_table(text: &str) -> Result<Vec<Curve>> {
    let mut curves: Vec<Curve> = Material::ALL
        .iter()
        .map(|_| Curve {
            energies: Vec::new(),
            values: Vec::new(),
            edges: Vec::new(),
            density: f64::NAN,
        })
        .collect();
    let mut header_seen = false;
    for (lineno, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if !header_seen {
            header_seen = true;
            continue;
        }
        let field = format!("line {}", lineno + 1);
        let cols: Vec<&str> = line.split(',').collect();
        if cols.len() < 4 {
            return Err(Error::invalid(field, "expected at least 4 columns"));
        }
        let Some(m) = Material::ALL.iter().position(|&m| table_name(m) == cols[0]) else {
            continue;
        };
        let num = |s: &str| {
            s.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| Error::invalid(&field, format!("bad number `{s}`")))
        };
        let (e, mu, rho) = (num(cols[1])?, num(cols[2])?, num(cols[3])?);
        let c = &mut curves[m];
        if c.energies.last().is_some_and(|&last| e <= last) {
            return Err(Error::invalid(field, "energies must increase"));
        }
        c.energies.push(e);
        c.values.push(mu);
        c.density = rho;
    }
    for (m, c) in Material::ALL.iter().zip(curves.iter_mut()) {
        if c.energies.len() < 4
            || c.energies[0] != TABLE_MIN_KEV
            || *c.energies.last().unwrap_or(&0.0) != TABLE_MAX_KEV
        {
            return Err(Error::invalid(
                table_name(*m),
                "table must span 10-150 keV with at least 4 points",
            ));
        }
        for i in 0..c.energies.len() - 1 {
            if c.values[i + 1] > c.values[i] {
                let (lo, hi) = (c.energies[i], c.energies[i + 1]);
                // A listed edge energy, or the interval's geometric centre if none is listed.
                let edge = ABSORPTION_EDGES
                    .iter()
                    .find(|(em, _, ek)| em == m && *ek > lo && *ek < hi)
                    .map_or((lo * hi).sqrt(), |e| e.2);
                c.edges.push((i, edge));
            }
        }
    }
    Ok(curves)
}

fn curves() -> &'static [Curve] {
    static CURVES: OnceLock<Vec<Curve>> = OnceLock::new();
    CURVES.get_or_init(|| {
        parse_table(TABLE_CSV).expect("embedded NIST table is malformed (build defect)")
    })
}

/// Check that `energy_kev` lies in the table's range; the error names `field`.
pub fn check_energy(energy_kev: f64, field: &str) -> Result<()> {
    if energy_kev.is_finite() && (TABLE_MIN_KEV..=TABLE_MAX_KEV).contains(&energy_kev) {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            format!(
                "{energy_kev} keV is outside the attenuation table ({TABLE_MIN_KEV}-{TABLE_MAX_KEV} keV)"
            ),
        ))
    }
}

impl Curve {
    /// The power law through the end points of interval `i`, evaluated at `e` (also outside it).
    fn power_law(&self, i: usize, e: f64) -> f64 {
        let (e0, e1) = (self.energies[i], self.energies[i + 1]);
        let (v0, v1) = (self.values[i], self.values[i + 1]);
        let k = (v1 / v0).ln() / (e1 / e0).ln();
        v0 * (e / e0).powf(k)
    }

    /// μ/ρ at `e` (within the table). On an edge interval each side extrapolates its outer
    /// neighbour interval; were an edge interval at an end of the table, that side would hold the
    /// tabulated value constant.
    fn eval(&self, e: f64) -> f64 {
        let n = self.energies.len();
        // Largest i with energies[i] <= e, as an interval index in 0..n-1.
        let i = (self.energies.partition_point(|&x| x <= e).max(1) - 1).min(n - 2);
        if e == self.energies[i] {
            return self.values[i];
        }
        if e == self.energies[i + 1] {
            return self.values[i + 1];
        }
        match self.edges.iter().find(|(j, _)| *j == i) {
            None => self.power_law(i, e),
            Some(&(_, edge)) if e < edge => {
                if i == 0 {
                    self.values[i]
                } else {
                    self.power_law(i - 1, e)
                }
            }
            Some(_) => {
                if i + 2 >= n {
                    self.values[i + 1]
                } else {
                    self.power_law(i + 1, e)
                }
            }
        }
    }
}

impl Material {
    /// Mass attenuation coefficient μ/ρ at `energy_kev`, cm²/g (log–log interpolation, sharp at
    /// absorption edges; see the module doc). Energies outside 10–150 keV are an error naming
    /// `energy_kev`.
    pub fn mu_over_rho(self, energy_kev: f64) -> Result<f64> {
        check_energy(energy_kev, "energy_kev")?;
        Ok(curves()[self as usize].eval(energy_kev))
    }

    /// Linear attenuation coefficient μ = (μ/ρ)·ρ of the pure material at its nominal density,
    /// in **mm⁻¹** (the table's cm⁻¹ divided by 10).
    pub fn mu(self, energy_kev: f64) -> Result<f64> {
        Ok(self.mu_over_rho(energy_kev)? * self.density() / 10.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    #[test]
    fn table_parses_for_every_material_and_densities_agree() {
        let c = curves();
        assert_eq!(c.len(), Material::ALL.len());
        for m in Material::ALL {
            let curve = &c[m as usize];
            assert_eq!(curve.energies.len(), 281, "{m:?}");
            assert_eq!(curve.density, m.density(), "{m:?} density");
        }
    }

    #[test]
    fn water_spot_values_match_nist() {
        // NIST XCOM / README spot values, cm²/g.
        for (e, want) in [
            (50.0, 0.2269),
            (60.0, 0.2059),
            (80.0, 0.1837),
            (100.0, 0.1707),
        ] {
            let got = Material::Water.mu_over_rho(e).unwrap();
            assert!(rel(got, want) < 0.005, "{e} keV: {got} vs {want}");
        }
        // μ in mm⁻¹ = μ/ρ·ρ/10.
        let mu = Material::Water.mu(60.0).unwrap();
        assert!(rel(mu, 0.02059) < 0.005);
        let bone = Material::CorticalBone;
        assert!(
            rel(
                bone.mu(60.0).unwrap(),
                bone.mu_over_rho(60.0).unwrap() * 1.92 / 10.0
            ) < 1e-15
        );
    }

    #[test]
    fn agrees_with_independent_nist_srd126_column() {
        // The table's last column is NIST SRD-126 (Hubbell–Seltzer), log-log interpolated from
        // NIST's coarser grid onto ours, independently of xraydb; for iron and titanium it is
        // Chantler's FFAST table (NIST SRD-66), at most 2.9 % from Elam's (titanium, 44 keV).
        // The largest gap overall is 3.8 % (dry air at 24.5 keV, midway between NIST's 20 and
        // 30 keV points, i.e. NIST's own interpolation error); 5 % pins that we read the right
        // column and material for every row, the iodine K-edge rows included.
        for line in TABLE_CSV.lines().filter(|l| !l.starts_with('#')).skip(1) {
            let cols: Vec<&str> = line.split(',').collect();
            let m = Material::ALL
                .into_iter()
                .find(|&m| table_name(m) == cols[0])
                .unwrap();
            let e: f64 = cols[1].parse().unwrap();
            let nist: f64 = cols[5].parse().unwrap();
            let got = m.mu_over_rho(e).unwrap();
            assert!(rel(got, nist) < 0.05, "{m:?} {e} keV: {got} vs {nist}");
        }
    }

    #[test]
    fn exact_at_grid_points_and_power_law_between() {
        for m in Material::ALL {
            let c = &curves()[m as usize];
            for i in 0..c.energies.len() {
                assert_eq!(m.mu_over_rho(c.energies[i]).unwrap(), c.values[i]);
            }
            for i in 0..c.energies.len() - 1 {
                if c.edges.iter().any(|(j, _)| *j == i) {
                    continue;
                }
                let (e0, e1, v0, v1) = (
                    c.energies[i],
                    c.energies[i + 1],
                    c.values[i],
                    c.values[i + 1],
                );
                // A power law through both ends takes the geometric mean of the values at the
                // geometric mean of the energies.
                let mid = m.mu_over_rho((e0 * e1).sqrt()).unwrap();
                assert!(rel(mid, (v0 * v1).sqrt()) < 1e-12, "{m:?} {e0}");
                // ... and at a quarter point in log-energy, v0^(3/4)·v1^(1/4).
                let q = m.mu_over_rho(e0.powf(0.75) * e1.powf(0.25)).unwrap();
                assert!(rel(q, v0.powf(0.75) * v1.powf(0.25)) < 1e-12, "{m:?} {e0}");
            }
        }
    }

    #[test]
    fn every_increasing_interval_is_a_listed_edge() {
        for m in Material::ALL {
            let c = &curves()[m as usize];
            for &(i, edge) in &c.edges {
                assert!(
                    ABSORPTION_EDGES
                        .iter()
                        .any(|(em, _, ek)| *em == m && *ek == edge),
                    "{m:?}: unlisted edge between {} and {} keV",
                    c.energies[i],
                    c.energies[i + 1]
                );
            }
        }
        assert_eq!(curves()[Material::Iodine as usize].edges.len(), 1);
    }

    #[test]
    fn iodine_k_edge_is_a_sharp_step() {
        let i = Material::Iodine;
        let below = i.mu(33.1).unwrap();
        let above = i.mu(33.3).unwrap();
        assert!(above / below > 4.0, "jump {below} -> {above}");
        // Just either side of 33.1694 keV: the step ratio of the tabulated neighbours (~5.3).
        let lo = i.mu_over_rho(33.169).unwrap();
        let hi = i.mu_over_rho(33.1694).unwrap();
        assert!(hi / lo > 5.0 && hi / lo < 5.8, "edge ratio {}", hi / lo);
        // Below the edge the curve keeps decreasing from the 33.0 keV point, above it decreases
        // towards the 33.5 keV point: no ramp, no overshoot beyond the neighbours' power laws.
        assert!(lo < i.mu_over_rho(33.0).unwrap());
        assert!(hi > i.mu_over_rho(33.5).unwrap());
        assert!(hi < 1.05 * i.mu_over_rho(33.5).unwrap());
    }

    #[test]
    fn monotone_decreasing_except_at_edges() {
        for m in Material::ALL {
            let mut prev = f64::INFINITY;
            let mut e = TABLE_MIN_KEV;
            while e <= TABLE_MAX_KEV {
                let v = m.mu_over_rho(e).unwrap();
                let crossed_edge = ABSORPTION_EDGES
                    .iter()
                    .any(|(em, _, ek)| *em == m && *ek <= e && *ek > e - 0.01);
                assert!(v.is_finite() && v > 0.0);
                assert!(crossed_edge || v <= prev, "{m:?} rises at {e} keV");
                prev = v;
                e += 0.01;
            }
        }
    }

    #[test]
    fn energy_outside_table_is_an_error_naming_the_field() {
        for e in [9.99, 150.01, f64::NAN, -1.0] {
            let msg = Material::Water.mu(e).unwrap_err().to_string();
            assert!(
                msg.contains("energy_kev") && msg.contains("10-150"),
                "{msg}"
            );
        }
        assert!(Material::Water.mu(10.0).is_ok() && Material::Water.mu(150.0).is_ok());
    }
}
