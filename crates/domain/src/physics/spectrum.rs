//! X-ray tube spectra (embedded SpekPy tables) and photon-counting energy windows.
//!
//! A [`Spectrum`] is a list of energy bins (bin centres, keV) with the relative photon fluence of
//! each bin; the weights sum to 1. Bin edges are implied by the centres: midway between
//! neighbouring centres, and mirrored at both ends (for the 1 keV tube tables, `[E − ½, E + ½]`).
//!
//! **Range.** The attenuation table starts at 10 keV, so [`Spectrum::tube`] keeps only the bins
//! whose centre lies in 10–150 keV and renormalises. For the embedded tables this drops the bins
//! at 1.5–9.5 keV, which 2.5 mm Al filtration has already emptied (< 1e-8 of the fluence; the
//! mean energies change by < 1e-6 keV).

use super::attenuation::{TABLE_MAX_KEV, TABLE_MIN_KEV};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fmt;

/// Added tube filtration of the embedded spectra.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Filtration {
    /// 2.5 mm aluminium (the usual inherent + added filtration of a clinical tube).
    #[default]
    #[serde(rename = "al2.5")]
    Al2_5,
    /// 2.5 mm aluminium plus 0.2 mm copper (a harder beam).
    #[serde(rename = "al2.5_cu0.2")]
    Al2_5Cu0_2,
}

impl Filtration {
    /// Every filtration with an embedded spectrum.
    pub const ALL: [Filtration; 2] = [Filtration::Al2_5, Filtration::Al2_5Cu0_2];

    /// The name used in files (`al2.5`, `al2.5_cu0.2`).
    pub fn name(self) -> &'static str {
        match self {
            Filtration::Al2_5 => "al2.5",
            Filtration::Al2_5Cu0_2 => "al2.5_cu0.2",
        }
    }
}

impl fmt::Display for Filtration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Tube voltages with an embedded spectrum, kVp.
pub const TUBE_KVPS: [u32; 6] = [40, 60, 80, 100, 120, 140];

/// Embedded SpekPy tables (tungsten anode, 12°, 1 keV bins; attribution in each file's header).
const TUBE_TABLES: [(u32, Filtration, &str); 12] = {
    use Filtration::{Al2_5 as A, Al2_5Cu0_2 as C};
    macro_rules! table {
        ($kvp:literal, $f:ident, $file:literal) => {
            (
                $kvp,
                $f,
                include_str!(concat!("../../data/spectra/", $file)),
            )
        };
    }
    [
        table!(40, A, "W_40kVp_Al2.5mm.csv"),
        table!(60, A, "W_60kVp_Al2.5mm.csv"),
        table!(80, A, "W_80kVp_Al2.5mm.csv"),
        table!(100, A, "W_100kVp_Al2.5mm.csv"),
        table!(120, A, "W_120kVp_Al2.5mm.csv"),
        table!(140, A, "W_140kVp_Al2.5mm.csv"),
        table!(40, C, "W_40kVp_Al2.5mm_Cu0.2mm.csv"),
        table!(60, C, "W_60kVp_Al2.5mm_Cu0.2mm.csv"),
        table!(80, C, "W_80kVp_Al2.5mm_Cu0.2mm.csv"),
        table!(100, C, "W_100kVp_Al2.5mm_Cu0.2mm.csv"),
        table!(120, C, "W_120kVp_Al2.5mm_Cu0.2mm.csv"),
        table!(140, C, "W_140kVp_Al2.5mm_Cu0.2mm.csv"),
    ]
};

/// Relative photon fluence per energy bin. Deserialising validates and normalises like
/// [`Spectrum::new`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawSpectrum")]
pub struct Spectrum {
    /// Bin centres, keV, strictly increasing.
    pub energies_kev: Vec<f64>,
    /// Relative photon fluence of each bin, ≥ 0, summing to 1.
    pub weights: Vec<f64>,
}

/// The serialised form of a [`Spectrum`], before validation.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSpectrum {
    energies_kev: Vec<f64>,
    weights: Vec<f64>,
}

impl TryFrom<RawSpectrum> for Spectrum {
    type Error = Error;
    fn try_from(raw: RawSpectrum) -> Result<Spectrum> {
        Spectrum::new(raw.energies_kev, raw.weights)
    }
}

impl Spectrum {
    /// A spectrum from bin centres and (unnormalised) fluences; the weights are normalised to sum
    /// to 1. Errors name `energies_kev` or `weights`.
    pub fn new(energies_kev: Vec<f64>, weights: Vec<f64>) -> Result<Spectrum> {
        if energies_kev.is_empty() {
            return Err(Error::invalid(
                "energies_kev",
                "a spectrum needs at least one bin",
            ));
        }
        if weights.len() != energies_kev.len() {
            return Err(Error::invalid(
                "weights",
                format!(
                    "{} weights for {} energies",
                    weights.len(),
                    energies_kev.len()
                ),
            ));
        }
        if energies_kev.iter().any(|e| !e.is_finite() || *e <= 0.0)
            || energies_kev.windows(2).any(|w| w[1] <= w[0])
        {
            return Err(Error::invalid(
                "energies_kev",
                "energies must be finite, positive and strictly increasing",
            ));
        }
        if weights.iter().any(|w| !w.is_finite() || *w < 0.0) {
            return Err(Error::invalid("weights", "weights must be finite and ≥ 0"));
        }
        let total: f64 = weights.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return Err(Error::invalid("weights", "the spectrum holds no photons"));
        }
        let weights = weights.into_iter().map(|w| w / total).collect();
        Ok(Spectrum {
            energies_kev,
            weights,
        })
    }

    /// The embedded tube spectrum for `kvp` and `filtration`, restricted to the attenuation table
    /// (bins centred in 10–150 keV, renormalised; see the module doc). An unknown kVp is an error
    /// naming `kvp` and listing the available ones.
    pub fn tube(kvp: u32, filtration: Filtration) -> Result<Spectrum> {
        tube_for_field(kvp, filtration, "kvp")
    }

    /// Mean photon energy Σ wᵢEᵢ / Σ wᵢ, keV.
    pub fn mean_energy(&self) -> f64 {
        let total: f64 = self.weights.iter().sum();
        self.energies_kev
            .iter()
            .zip(&self.weights)
            .map(|(e, w)| e * w)
            .sum::<f64>()
            / total
    }

    /// Bin edges implied by the centres (`n + 1` values): midway between centres, mirrored at
    /// the ends. A single bin has zero width.
    pub fn bin_edges(&self) -> Vec<f64> {
        let e = &self.energies_kev;
        let n = e.len();
        let mut edges = Vec::with_capacity(n + 1);
        if n == 1 {
            return vec![e[0], e[0]];
        }
        edges.push(e[0] - 0.5 * (e[1] - e[0]));
        edges.extend(e.windows(2).map(|w| 0.5 * (w[0] + w[1])));
        edges.push(e[n - 1] + 0.5 * (e[n - 1] - e[n - 2]));
        edges
    }

    /// The fraction of the photons with energy in `[lo_kev, hi_kev]`, fluence taken as uniform
    /// within a bin (as [`Spectrum::window`] does); 0 for an empty or inverted window.
    pub fn fraction(&self, lo_kev: f64, hi_kev: f64) -> f64 {
        let edges = self.bin_edges();
        let total: f64 = self.weights.iter().sum();
        let inside: f64 = self
            .weights
            .iter()
            .enumerate()
            .map(|(i, &w)| {
                let (a, b) = (edges[i], edges[i + 1]);
                if b <= a {
                    return if (lo_kev..=hi_kev).contains(&a) {
                        w
                    } else {
                        0.0
                    };
                }
                let overlap = (b.min(hi_kev) - a.max(lo_kev)).max(0.0);
                w * overlap / (b - a)
            })
            .sum();
        if total > 0.0 { inside / total } else { 0.0 }
    }

    /// The photons with energy in `[lo_kev, hi_kev]`, renormalised: a photon-counting energy
    /// window. Fluence is taken as uniform within a bin, so a bin cut by the window keeps the
    /// overlapping fraction of its weight, centred on the overlap. A window holding no photons is
    /// an error naming `lo_kev`/`hi_kev`.
    pub fn window(&self, lo_kev: f64, hi_kev: f64) -> Result<Spectrum> {
        self.window_split(lo_kev, hi_kev, &[])
    }

    /// [`Spectrum::window`] with bins also split at the energies `cuts` (each piece keeps its
    /// share of the bin's fluence, at its own midpoint). The result lists quadrature nodes:
    /// its implied bin edges no longer match the original bins.
    pub(crate) fn window_split(&self, lo_kev: f64, hi_kev: f64, cuts: &[f64]) -> Result<Spectrum> {
        if !lo_kev.is_finite() || lo_kev < 0.0 {
            return Err(Error::invalid(
                "lo_kev",
                format!("{lo_kev} keV must be finite and ≥ 0"),
            ));
        }
        if !hi_kev.is_finite() || hi_kev <= lo_kev {
            return Err(Error::invalid(
                "hi_kev",
                format!("{hi_kev} keV must be finite and above lo_kev = {lo_kev} keV"),
            ));
        }
        let edges = self.bin_edges();
        let (mut energies, mut weights) = (Vec::new(), Vec::new());
        for (i, &w) in self.weights.iter().enumerate() {
            let (a, b) = (edges[i], edges[i + 1]);
            if b <= a {
                // A zero-width bin (single-bin spectrum) is in or out as a whole.
                if w > 0.0 && (lo_kev..=hi_kev).contains(&a) {
                    energies.push(a);
                    weights.push(w);
                }
                continue;
            }
            let (lo, hi) = (a.max(lo_kev), b.min(hi_kev));
            if w <= 0.0 || hi <= lo {
                continue;
            }
            let mut bounds = vec![lo];
            bounds.extend(cuts.iter().copied().filter(|&c| c > lo && c < hi));
            bounds.push(hi);
            bounds.sort_by(f64::total_cmp);
            for piece in bounds.windows(2) {
                energies.push(0.5 * (piece[0] + piece[1]));
                weights.push(w * (piece[1] - piece[0]) / (b - a));
            }
        }
        if weights.is_empty() {
            let (first, last) = (edges[0], edges[edges.len() - 1]);
            return Err(Error::invalid(
                "lo_kev..hi_kev",
                format!(
                    "the window [{lo_kev}, {hi_kev}] keV holds no photons \
                     (the spectrum spans {first}-{last} keV)"
                ),
            ));
        }
        Spectrum::new(energies, weights)
    }
}

/// [`Spectrum::tube`] with the kVp error naming `field` (e.g. `low_kvp`).
pub(crate) fn tube_for_field(kvp: u32, filtration: Filtration, field: &str) -> Result<Spectrum> {
    let Some(&(_, _, text)) = TUBE_TABLES
        .iter()
        .find(|(k, f, _)| *k == kvp && *f == filtration)
    else {
        let known: Vec<String> = TUBE_KVPS.iter().map(|k| k.to_string()).collect();
        return Err(Error::invalid(
            field,
            format!(
                "no tube spectrum for {kvp} kVp (available: {} kVp)",
                known.join(", ")
            ),
        ));
    };
    let (mut energies, mut weights) = (Vec::new(), Vec::new());
    for line in text.lines().filter(|l| !l.starts_with('#')).skip(1) {
        let mut cols = line.split(',').map(|c| c.trim().parse::<f64>());
        match (cols.next(), cols.next()) {
            (Some(Ok(e)), Some(Ok(w))) => {
                if (TABLE_MIN_KEV..=TABLE_MAX_KEV).contains(&e) {
                    energies.push(e);
                    weights.push(w);
                }
            }
            _ => {
                return Err(Error::invalid(
                    field,
                    format!("embedded {kvp} kVp spectrum has a bad line `{line}`"),
                ));
            }
        }
    }
    Spectrum::new(energies, weights)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat spectrum of 1 keV bins from 10 to 20 keV: a window's share is its width over
    /// 10 keV, bins cut by it counting by their overlap; windows that tile it sum to 1.
    #[test]
    fn the_fraction_in_a_window_counts_bins_by_their_overlap() {
        let s = Spectrum::new((0..10).map(|i| 10.5 + i as f64).collect(), vec![1.0; 10]).unwrap();
        assert!((s.fraction(10.0, 20.0) - 1.0).abs() < 1e-12);
        assert!((s.fraction(12.0, 15.0) - 0.3).abs() < 1e-12);
        assert!((s.fraction(12.25, 12.75) - 0.05).abs() < 1e-12);
        assert!((s.fraction(0.0, 12.5) + s.fraction(12.5, 99.0) - 1.0).abs() < 1e-12);
        assert_eq!(s.fraction(30.0, 40.0), 0.0);
        assert_eq!(s.fraction(15.0, 12.0), 0.0);
    }

    #[test]
    fn every_embedded_spectrum_loads_and_sums_to_one() {
        for f in Filtration::ALL {
            for kvp in TUBE_KVPS {
                let s = Spectrum::tube(kvp, f).unwrap();
                let total: f64 = s.weights.iter().sum();
                assert!((total - 1.0).abs() < 1e-12, "{kvp} {f}: {total}");
                assert_eq!(s.energies_kev[0], 10.5);
                // 1 keV bins up to the bin below the peak voltage.
                assert_eq!(*s.energies_kev.last().unwrap(), kvp as f64 - 0.5);
                assert_eq!(s.energies_kev.len(), kvp as usize - 10);
            }
        }
    }

    #[test]
    fn mean_energies_match_spekpy_summary() {
        // README (rounded to 0.1 keV) and SpekPy's summary.json (3 decimals), computed over all
        // bins from 1.5 keV. Dropping the < 10 keV bins removes < 1e-8 of the fluence, which
        // moves a mean by < 1e-6 keV, so the only discrepancy is the summary's rounding to
        // 0.0005 keV: 1e-3 keV is a safe bound (and far inside the 0.2 keV asked for).
        let summary = [
            (40, Filtration::Al2_5, 28.102),
            (60, Filtration::Al2_5, 35.953),
            (80, Filtration::Al2_5, 42.903),
            (100, Filtration::Al2_5, 49.148),
            (120, Filtration::Al2_5, 54.447),
            (140, Filtration::Al2_5, 59.152),
            (40, Filtration::Al2_5Cu0_2, 32.582),
            (60, Filtration::Al2_5Cu0_2, 42.576),
            (80, Filtration::Al2_5Cu0_2, 50.911),
            (100, Filtration::Al2_5Cu0_2, 57.677),
            (120, Filtration::Al2_5Cu0_2, 63.194),
            (140, Filtration::Al2_5Cu0_2, 68.109),
        ];
        for (kvp, f, want) in summary {
            let got = Spectrum::tube(kvp, f).unwrap().mean_energy();
            assert!((got - want).abs() < 1e-3, "{kvp} kVp {f}: {got} vs {want}");
        }
        for (kvp, readme) in [(40, 28.1), (60, 36.0), (80, 42.9), (100, 49.1)] {
            let got = Spectrum::tube(kvp, Filtration::Al2_5)
                .unwrap()
                .mean_energy();
            assert!((got - readme).abs() < 0.2, "{kvp}: {got}");
        }
    }

    #[test]
    fn unknown_kvp_names_the_field_and_lists_choices() {
        let msg = Spectrum::tube(90, Filtration::Al2_5)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("`kvp`") && msg.contains("40, 60, 80, 100, 120, 140"),
            "{msg}"
        );
    }

    #[test]
    fn window_restricts_and_renormalises() {
        let s = Spectrum::tube(80, Filtration::Al2_5).unwrap();
        let w = s.window(30.0, 50.0).unwrap();
        // Whole bins 30.5..=49.5 keV, weights proportional to the parent's.
        assert_eq!(w.energies_kev.len(), 20);
        assert_eq!(w.energies_kev[0], 30.5);
        let parent: f64 = s.weights[20..40].iter().sum();
        for (i, wi) in w.weights.iter().enumerate() {
            assert!((wi - s.weights[20 + i] / parent).abs() < 1e-15);
        }
        assert!((w.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // A window inside one bin ([60, 61] keV) keeps one sub-bin centred in the window.
        let narrow = s.window(60.35, 60.45).unwrap();
        assert_eq!(narrow.energies_kev.len(), 1);
        assert!((narrow.energies_kev[0] - 60.4).abs() < 1e-12);
        assert_eq!(narrow.weights, vec![1.0]);
        // One across a bin edge keeps a sub-bin on each side, weighted by overlap.
        let across = s.window(59.9, 60.2).unwrap();
        assert_eq!(across.energies_kev.len(), 2);
        assert!((across.energies_kev[0] - 59.95).abs() < 1e-12);
        assert!((across.energies_kev[1] - 60.1).abs() < 1e-12);
        let want = 0.1 * s.weights[49] / (0.1 * s.weights[49] + 0.2 * s.weights[50]);
        assert!((across.weights[0] - want).abs() < 1e-12);
        // Cutting a bin in half keeps half its weight.
        let half = s.window(30.0, 31.0).unwrap().weights[0];
        let half2 = s.window(30.5, 32.0).unwrap();
        let expect = 0.5 * s.weights[20] / (0.5 * s.weights[20] + s.weights[21]);
        assert!((half - 1.0).abs() < 1e-15 && (half2.weights[0] - expect).abs() < 1e-12);
    }

    #[test]
    fn bad_windows_and_spectra_name_their_fields() {
        let s = Spectrum::tube(60, Filtration::Al2_5).unwrap();
        let msg = s.window(70.0, 90.0).unwrap_err().to_string();
        assert!(
            msg.contains("lo_kev..hi_kev") && msg.contains("no photons"),
            "{msg}"
        );
        let msg = s.window(40.0, 40.0).unwrap_err().to_string();
        assert!(msg.contains("`hi_kev`"), "{msg}");
        let msg = s.window(f64::NAN, 40.0).unwrap_err().to_string();
        assert!(msg.contains("`lo_kev`"), "{msg}");
        let msg = Spectrum::new(vec![], vec![]).unwrap_err().to_string();
        assert!(msg.contains("energies_kev"), "{msg}");
        let msg = Spectrum::new(vec![20.0], vec![0.0])
            .unwrap_err()
            .to_string();
        assert!(msg.contains("weights"), "{msg}");
        let msg = Spectrum::new(vec![30.0, 20.0], vec![1.0, 1.0])
            .unwrap_err()
            .to_string();
        assert!(msg.contains("energies_kev"), "{msg}");
    }

    #[test]
    fn deserialising_validates_and_normalises() {
        let s: Spectrum =
            serde_yaml_ng::from_str("{energies_kev: [30, 40], weights: [1, 3]}").unwrap();
        assert_eq!(s.weights, vec![0.25, 0.75]);
        assert!((s.mean_energy() - 37.5).abs() < 1e-12);
        let bad = serde_yaml_ng::from_str::<Spectrum>("{energies_kev: [30], weights: [-1]}");
        assert!(bad.unwrap_err().to_string().contains("weights"));
    }

    #[test]
    fn filtration_serde_names() {
        for f in Filtration::ALL {
            let y = serde_yaml_ng::to_string(&f).unwrap();
            assert_eq!(y.trim(), f.name());
            assert_eq!(serde_yaml_ng::from_str::<Filtration>(f.name()).unwrap(), f);
        }
        assert_eq!(Filtration::default(), Filtration::Al2_5);
    }
}
