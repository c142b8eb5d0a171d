//! Spectral channel synthesis: from material path lengths to one channel's projections, and from
//! material fractions to the channel's reference attenuation volume.
//!
//! Inputs are per material: path lengths `L_m` (`[view][row][col]`, mm of the pure material at
//! its nominal density, i.e. ∫ fraction dl) for projections, fraction volumes `f_m`
//! (`[z][y][x]`, dimensionless) for reference volumes. Outputs are line integrals
//! (dimensionless) and μ in mm⁻¹.
//!
//! | kind | projection p | reference volume |
//! |---|---|---|
//! | `mono` | Σ_m μ_m(E)·L_m | Σ_m μ_m(E)·f_m |
//! | `mixed` | λ·p(μ̄(low kVp)) + (1−λ)·p(μ̄(high kVp)) | same blend of μ̄ |
//! | `polychromatic` | −ln Σ_E S(E)·exp(−Σ_m μ_m(E)·L_m) | Σ_m μ̄_m·f_m |
//! | `window` | as `polychromatic` with S restricted to [lo, hi] | Σ_m μ̄_m·f_m |
//!
//! Sums over E run over the spectrum's 1 keV bins evaluated at their centres, except that a bin
//! straddling an absorption edge is split at the edge, so that no node averages across the
//! step ([`ChannelSpec::spectrum`] returns these nodes).
//!
//! The **effective coefficient** of a spectrum is the fluence-weighted mean
//! `μ̄_m = Σ_E S(E)·μ_m(E)` (S sums to 1): it is the slope of the polychromatic projection at zero
//! thickness, so the reference volume is what the scan "sees" for thin objects. The detector
//! counts photons (each detected photon weighs 1, as in a photon-counting bin); an
//! energy-integrating detector would weigh them by E, which this model does not do.

use super::Material;
use super::attenuation::{ABSORPTION_EDGES, check_energy};
use super::spectrum::{Filtration, Spectrum, tube_for_field};
use crate::{Error, Result};
use ndarray::{Array3, CowArray, Ix3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How one energy channel is formed. Serialised with a `kind` tag, e.g.
/// `{kind: mono, kev: 60}` or `{kind: window, lo_kev: 20, hi_kev: 40, kvp: 120}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ChannelSpec {
    /// Monoenergetic beam at `kev`.
    Mono { kev: f64 },
    /// Blend λ·V_low + (1−λ)·V_high of two kVp-effective attenuation maps (0 ≤ λ ≤ 1).
    Mixed {
        lambda: f64,
        low_kvp: u32,
        high_kvp: u32,
        #[serde(default)]
        filtration: Filtration,
    },
    /// Polychromatic tube beam at `kvp` (with beam hardening).
    Polychromatic {
        kvp: u32,
        #[serde(default)]
        filtration: Filtration,
    },
    /// Photon-counting energy bin [lo_kev, hi_kev] of a `kvp` tube beam (with beam hardening).
    Window {
        lo_kev: f64,
        hi_kev: f64,
        kvp: u32,
        #[serde(default)]
        filtration: Filtration,
    },
}

/// Number of materials, for per-material coefficient arrays indexed by `m as usize`.
const N_MATERIALS: usize = Material::ALL.len();

/// A channel prepared for synthesis: per-material coefficients tabulated once.
enum Compiled {
    /// p = Σ_m c_m·L_m (mm⁻¹ coefficients).
    Linear { coef: [f64; N_MATERIALS] },
    /// Polychromatic: positive weights S(E), μ_m(E) per material, and μ̄_m.
    Spectral {
        weights: Vec<f64>,
        mu: Box<[Vec<f64>; N_MATERIALS]>,
        effective: [f64; N_MATERIALS],
    },
}

/// μ_m(E) for every material at `energies` (already checked to lie in the table).
fn mu_table(energies: &[f64]) -> Result<[Vec<f64>; N_MATERIALS]> {
    let mut table: [Vec<f64>; N_MATERIALS] = Default::default();
    for m in Material::ALL {
        table[m as usize] = energies.iter().map(|&e| m.mu(e)).collect::<Result<_>>()?;
    }
    Ok(table)
}

/// Quadrature nodes of a spectrum restricted to [lo, hi]: the bins at their centres, clipped to
/// the window, and with every bin that straddles an absorption edge (iodine K, 33.17 keV, inside
/// the 33–34 keV bin) split at the edge into two pieces at their own midpoints (fluence taken as
/// uniform within a bin). Without the split the whole bin would see the above-edge μ. Only
/// positive weights remain (the stable log-sum needs them).
fn quadrature(spectrum: &Spectrum, lo_kev: f64, hi_kev: f64) -> Result<Spectrum> {
    let cuts: Vec<f64> = ABSORPTION_EDGES.iter().map(|&(_, _, k)| k).collect();
    spectrum.window_split(lo_kev, hi_kev, &cuts)
}

/// A whole tube spectrum's quadrature nodes (a window wider than any spectrum).
fn full_quadrature(spectrum: &Spectrum) -> Result<Spectrum> {
    quadrature(spectrum, 0.0, f64::MAX)
}

/// The two tube spectra a mixed channel blends (errors name `low_kvp`, `high_kvp`).
fn mixed_tubes(
    low_kvp: u32,
    high_kvp: u32,
    filtration: Filtration,
) -> Result<(Spectrum, Spectrum)> {
    Ok((
        tube_for_field(low_kvp, filtration, "low_kvp")?,
        tube_for_field(high_kvp, filtration, "high_kvp")?,
    ))
}

/// Fluence-weighted effective coefficients μ̄_m = Σ_E S(E)·μ_m(E) over quadrature nodes, mm⁻¹.
fn effective(nodes: &Spectrum) -> Result<[f64; N_MATERIALS]> {
    let mu = mu_table(&nodes.energies_kev)?;
    Ok(std::array::from_fn(|m| {
        nodes.weights.iter().zip(&mu[m]).map(|(w, u)| w * u).sum()
    }))
}

impl ChannelSpec {
    /// A short name for the channel: `40keV`, `lambda0.3`, `80kVp` (with `_<filtration>` for a
    /// non-default filtration), `20-90keV`.
    pub fn label(&self) -> String {
        match self {
            ChannelSpec::Mono { kev } => format!("{kev}keV"),
            ChannelSpec::Mixed { lambda, .. } => format!("lambda{lambda}"),
            ChannelSpec::Polychromatic { kvp, filtration } => {
                if *filtration == Filtration::default() {
                    format!("{kvp}kVp")
                } else {
                    format!("{kvp}kVp_{filtration}")
                }
            }
            ChannelSpec::Window { lo_kev, hi_kev, .. } => format!("{lo_kev}-{hi_kev}keV"),
        }
    }

    /// The channel's scalar physical coordinate, the axis along which channels are ordered:
    /// `mono` → energy (keV), `mixed` → λ, `polychromatic` → kVp, `window` → lower edge (keV).
    pub fn coordinate(&self) -> f64 {
        match self {
            ChannelSpec::Mono { kev } => *kev,
            ChannelSpec::Mixed { lambda, .. } => *lambda,
            ChannelSpec::Polychromatic { kvp, .. } => *kvp as f64,
            ChannelSpec::Window { lo_kev, .. } => *lo_kev,
        }
    }

    /// The spectrum a polychromatic or window channel integrates over, as quadrature nodes
    /// (window applied, bins split at absorption edges; see the module doc); `None` for mono and
    /// mixed. Errors name `kvp`, `lo_kev`, `hi_kev`.
    pub fn spectrum(&self) -> Result<Option<Spectrum>> {
        match *self {
            ChannelSpec::Mono { .. } | ChannelSpec::Mixed { .. } => Ok(None),
            ChannelSpec::Polychromatic { kvp, filtration } => {
                full_quadrature(&tube_for_field(kvp, filtration, "kvp")?).map(Some)
            }
            ChannelSpec::Window {
                lo_kev,
                hi_kev,
                kvp,
                filtration,
            } => quadrature(&tube_for_field(kvp, filtration, "kvp")?, lo_kev, hi_kev).map(Some),
        }
    }

    /// The share of a tube's photons this channel counts: for a photon-counting window, the
    /// fraction of the `kvp` spectrum's photons in `[lo_kev, hi_kev]`
    /// ([`Spectrum::fraction`]); 1 for every other kind (the whole beam). Errors name `kvp`.
    pub fn photon_share(&self) -> Result<f64> {
        match *self {
            ChannelSpec::Window {
                lo_kev,
                hi_kev,
                kvp,
                filtration,
            } => Ok(tube_for_field(kvp, filtration, "kvp")?.fraction(lo_kev, hi_kev)),
            _ => Ok(1.0),
        }
    }

    /// Check every parameter (energies in the table, λ in [0, 1], known kVps, non-empty
    /// window); errors name the field (`kev`, `lambda`, `low_kvp`, `kvp`, `lo_kev`, ...).
    pub fn validate(&self) -> Result<()> {
        self.compile().map(|_| ())
    }

    /// Effective linear attenuation of pure `material` in this channel, mm⁻¹: μ(E) for mono,
    /// the λ-blend of kVp-effective coefficients for mixed, μ̄ (see module doc) otherwise. The
    /// reference volume is Σ_m effective_mu(m)·f_m.
    pub fn effective_mu(&self, material: Material) -> Result<f64> {
        Ok(self.compile()?.coefficients()[material as usize])
    }

    /// The energy the channel is centred on, keV: its energy (mono), its spectrum's
    /// fluence-weighted mean (polychromatic, window) or the λ-blend of the two tubes' means
    /// (mixed). Used to say whether an energy lies among the observed channels.
    pub fn mean_kev(&self) -> Result<f64> {
        Ok(match *self {
            ChannelSpec::Mono { kev } => kev,
            ChannelSpec::Mixed {
                lambda,
                low_kvp,
                high_kvp,
                filtration,
            } => {
                let (low, high) = mixed_tubes(low_kvp, high_kvp, filtration)?;
                lambda * low.mean_energy() + (1.0 - lambda) * high.mean_energy()
            }
            _ => self
                .spectrum()?
                .expect("spectral channel has a spectrum")
                .mean_energy(),
        })
    }

    /// This channel's forward model restricted to `materials`: quadrature nodes `(weight,
    /// μ per material in mm⁻¹)` with `p = −ln Σ_n w_n·exp(−Σ_j μ_nj·L_j)` (weights sum to 1).
    /// A linear channel (`mono`, `mixed`) is one node of weight 1, so p = Σ_j μ_j·L_j exactly;
    /// a spectral one (`polychromatic`, `window`) has the nodes [`ChannelSpec::project`] sums
    /// over. This is how a model that carries material path lengths reproduces the synthesis.
    pub fn nodes(&self, materials: &[Material]) -> Result<Vec<(f64, Vec<f64>)>> {
        Ok(match self.compile()? {
            Compiled::Linear { coef } => {
                vec![(1.0, materials.iter().map(|&m| coef[m as usize]).collect())]
            }
            Compiled::Spectral { weights, mu, .. } => {
                let total: f64 = weights.iter().sum();
                weights
                    .iter()
                    .enumerate()
                    .map(|(e, w)| {
                        (
                            w / total,
                            materials.iter().map(|&m| mu[m as usize][e]).collect(),
                        )
                    })
                    .collect()
            }
        })
    }

    fn compile(&self) -> Result<Compiled> {
        match *self {
            ChannelSpec::Mono { kev } => {
                check_energy(kev, "kev")?;
                let mut coef = [0.0; N_MATERIALS];
                for m in Material::ALL {
                    coef[m as usize] = m.mu(kev)?;
                }
                Ok(Compiled::Linear { coef })
            }
            ChannelSpec::Mixed {
                lambda,
                low_kvp,
                high_kvp,
                filtration,
            } => {
                if !(0.0..=1.0).contains(&lambda) {
                    return Err(Error::invalid(
                        "lambda",
                        format!("{lambda} must lie in [0, 1]"),
                    ));
                }
                let (low, high) = mixed_tubes(low_kvp, high_kvp, filtration)?;
                let low = effective(&full_quadrature(&low)?)?;
                let high = effective(&full_quadrature(&high)?)?;
                let coef = std::array::from_fn(|m| lambda * low[m] + (1.0 - lambda) * high[m]);
                Ok(Compiled::Linear { coef })
            }
            ChannelSpec::Polychromatic { .. } | ChannelSpec::Window { .. } => {
                let nodes = self.spectrum()?.expect("spectral channel has a spectrum");
                let effective = effective(&nodes)?;
                let Spectrum {
                    energies_kev: energies,
                    weights,
                } = nodes;
                Ok(Compiled::Spectral {
                    mu: Box::new(mu_table(&energies)?),
                    weights,
                    effective,
                })
            }
        }
    }

    /// Synthesise this channel's projections `[view][row][col]` from material path lengths (mm,
    /// see the module doc). All arrays must share one shape; errors name `paths`.
    pub fn project(&self, paths: &[(Material, Array3<f32>)]) -> Result<Array3<f32>> {
        let compiled = self.compile()?;
        let (shape, arrays) = gather(paths, "paths")?;
        let inputs = slices(&arrays);
        let out = match &compiled {
            Compiled::Linear { coef } => linear_combination(coef, &inputs),
            Compiled::Spectral { weights, mu, .. } => {
                let rows: Vec<(&[f64], &[f32])> = inputs
                    .iter()
                    .map(|(m, l)| (mu[*m as usize].as_slice(), *l))
                    .collect();
                polychromatic(weights, &rows)
            }
        };
        Ok(Array3::from_shape_vec(shape, out).expect("output has the input's length"))
    }

    /// This channel's reference attenuation volume `[z][y][x]` (μ, mm⁻¹) from material fraction
    /// volumes: Σ_m effective_mu(m)·f_m. All arrays must share one shape; errors name `fractions`.
    pub fn volume(&self, fractions: &[(Material, Array3<f32>)]) -> Result<Array3<f32>> {
        let coef = self.compile()?.coefficients();
        let (shape, arrays) = gather(fractions, "fractions")?;
        let inputs = slices(&arrays);
        let out = linear_combination(&coef, &inputs);
        Ok(Array3::from_shape_vec(shape, out).expect("output has the input's length"))
    }
}

impl Compiled {
    fn coefficients(&self) -> [f64; N_MATERIALS] {
        match self {
            Compiled::Linear { coef } => *coef,
            Compiled::Spectral { effective, .. } => *effective,
        }
    }
}

/// Flat standard-layout slices of the inputs.
type Inputs<'a> = Vec<(Material, &'a [f32])>;

/// Shape and standard-layout inputs.
type Gathered<'a> = (
    (usize, usize, usize),
    Vec<(Material, CowArray<'a, f32, Ix3>)>,
);

/// The inputs in standard layout (borrowed when they already are), validated: non-empty, one
/// shape, finite.
fn gather<'a>(arrays: &'a [(Material, Array3<f32>)], field: &str) -> Result<Gathered<'a>> {
    let Some((_, first)) = arrays.first() else {
        return Err(Error::invalid(field, "at least one material is needed"));
    };
    let shape = first.dim();
    let mut out = Vec::with_capacity(arrays.len());
    for (i, (m, a)) in arrays.iter().enumerate() {
        let name = format!("{field}[{i}] ({})", m.name());
        if a.dim() != shape {
            return Err(Error::invalid(
                name,
                format!("shape {:?} differs from {:?} of {field}[0]", a.dim(), shape),
            ));
        }
        if let Some((idx, v)) = a
            .iter()
            .any(|v| !v.is_finite())
            .then(|| a.indexed_iter().find(|(_, v)| !v.is_finite()))
            .flatten()
        {
            return Err(Error::invalid(
                name,
                format!("non-finite value {v} at index {idx:?}"),
            ));
        }
        out.push((*m, a.as_standard_layout()));
    }
    Ok((shape, out))
}

fn slices<'a>(arrays: &'a [(Material, CowArray<'_, f32, Ix3>)]) -> Inputs<'a> {
    arrays
        .iter()
        .map(|(m, a)| (*m, a.as_slice().expect("standard layout")))
        .collect()
}

/// Pixels per parallel task.
const CHUNK: usize = 4096;

/// Σ_j coef[m_j]·x_j per element, in f64.
fn linear_combination(coef: &[f64; N_MATERIALS], inputs: &Inputs) -> Vec<f32> {
    let n = inputs[0].1.len();
    let mut out = vec![0.0f32; n];
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let base = c * CHUNK;
            for (t, o) in chunk.iter_mut().enumerate() {
                let k = base + t;
                *o = inputs
                    .iter()
                    .map(|(m, x)| coef[*m as usize] * x[k] as f64)
                    .sum::<f64>() as f32;
            }
        });
    out
}

/// p = −ln Σ_E S_E·exp(−a_E) with a_E = Σ_j μ_j(E)·L_j, per pixel.
///
/// Stable form: with a* = min_E a_E, p = a* − ln(Σ_E S_E·exp(−(a_E − a*)) / Σ_E S_E). Every
/// exponent is ≤ 0 (no overflow) and the term at a* is S_E > 0 (no underflow to 0), so p is
/// finite for any finite input; zero thickness gives a ≡ 0 and the ratio of two identical sums,
/// hence exactly 0 (returned directly, without the sum, for rays that meet no material).
fn polychromatic(weights: &[f64], rows: &[(&[f64], &[f32])]) -> Vec<f32> {
    let n = rows[0].1.len();
    let n_e = weights.len();
    // Σ_E S_E summed in the same order as the per-pixel sum (whose terms are S_E·1 at a ≡ 0).
    let total: f64 = weights.iter().sum();
    let mut out = vec![0.0f32; n];
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let base = c * CHUNK;
            let mut a = vec![0.0f64; n_e];
            for (t, o) in chunk.iter_mut().enumerate() {
                let k = base + t;
                // A ray that meets no material (common: air around the object) is exactly 0.
                if rows.iter().all(|(_, l)| l[k] == 0.0) {
                    *o = 0.0;
                    continue;
                }
                a.fill(0.0);
                for (mu, l) in rows {
                    let l = l[k] as f64;
                    if l != 0.0 {
                        for (ae, u) in a.iter_mut().zip(mu.iter()) {
                            *ae += u * l;
                        }
                    }
                }
                let a_min = a.iter().copied().fold(f64::INFINITY, f64::min);
                let sum: f64 = weights
                    .iter()
                    .zip(&a)
                    .map(|(w, ae)| w * (-(ae - a_min)).exp())
                    .sum();
                *o = (a_min - (sum / total).ln()) as f32;
            }
        });
    out
}

#[cfg(test)]
mod tests;
