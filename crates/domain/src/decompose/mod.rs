//! Basis-material decomposition and virtual monoenergetic images (VMI) from per-channel
//! attenuation volumes.
//!
//! Model: in channel s the attenuation is a non-negative combination of basis materials,
//! `μ(x, s) = Σ_b ρ_b(x)·μ̄_b(s)`, where `μ̄_b(s)` is the channel's effective attenuation of pure
//! material b at its nominal density ([`ChannelSpec::effective_mu`], mm⁻¹: μ(E) for a mono
//! channel, the fluence-weighted mean for a spectrum, as the simulator forms reference volumes)
//! and `ρ_b` is the volume fraction of b at that density (ρ_b × density_b is g/cm³). Given the
//! channel volumes `μ_c(x)` the fractions are, voxel by voxel, the non-negative least-squares
//! solution ([`Decomposition::solve`]): the image-domain step of a two-step decomposition.
//!
//! A VMI at E keV is `Σ_b ρ_b(x)·μ_b(E)` ([`vmi`]), defined wherever the attenuation table is
//! (10–150 keV); outside the channels' energies it extrapolates the basis model.
//!
//! **Separability.** With channel matrix `A` (`[channel][basis]`), a noise of σ mm⁻¹ in every
//! channel volume becomes a standard deviation of `g_b·σ` in fraction b, `g_b = √((AᵀA)⁻¹)_bb`
//! ([`Separability::noise_gain`]). The condition number of A with unit-norm columns says how
//! nearly two basis materials look alike across the channels; above [`MAX_CONDITION`] (or with
//! fewer channels than basis materials) the channels cannot separate the basis and
//! [`Decomposition::new`] refuses it, naming the pair that looks most alike.

use crate::physics::{ChannelSpec, Material};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

#[cfg(test)]
mod tests;

/// The most basis materials a decomposition takes.
pub const MAX_BASIS: usize = 4;

/// Condition number (unit-norm columns) above which the channels are said not to separate the
/// basis: a 0.1 % error in the channel volumes can then become a 100 % error in a fraction.
pub const MAX_CONDITION: f64 = 1e3;

/// A set of distinct basis materials (water, cortical bone, iodine by default).
#[derive(Clone, Debug, PartialEq)]
pub struct Basis {
    materials: Vec<Material>,
}

impl Basis {
    /// Water, cortical bone and iodine: soft tissue, bone and contrast agent.
    pub fn body() -> Basis {
        Basis {
            materials: vec![Material::Water, Material::CorticalBone, Material::Iodine],
        }
    }

    /// 1 to [`MAX_BASIS`] distinct materials; errors name `basis`.
    pub fn new(materials: &[Material]) -> Result<Basis> {
        if materials.is_empty() || materials.len() > MAX_BASIS {
            return Err(Error::invalid(
                "basis",
                format!("give 1 to {MAX_BASIS} materials, got {}", materials.len()),
            ));
        }
        for (i, m) in materials.iter().enumerate() {
            if materials[..i].contains(m) {
                return Err(Error::invalid(
                    "basis",
                    format!("{} is listed twice", m.name()),
                ));
            }
        }
        Ok(Basis {
            materials: materials.to_vec(),
        })
    }

    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// μ_b(E) of every basis material at `kev`, mm⁻¹.
    pub fn mu(&self, kev: f64) -> Result<Vec<f64>> {
        self.materials.iter().map(|m| m.mu(kev)).collect()
    }

    /// The non-negative basis mixture whose attenuation best matches pure `material`'s over
    /// `energies` (keV; least squares in μ, as [`Decomposition::solve`] fits a voxel): the
    /// basis-equivalent fractions of a unit fraction of it. A basis material's own equivalent
    /// is its unit vector. Errors when the energies cannot separate the basis.
    pub fn equivalent(&self, material: Material, energies: &[f64]) -> Result<Vec<f64>> {
        let mono: Vec<ChannelSpec> = energies
            .iter()
            .map(|&kev| ChannelSpec::Mono { kev })
            .collect();
        let d = Decomposition::new(self.clone(), &mono).map_err(|e| e.under("energies"))?;
        let target: Vec<f64> = energies
            .iter()
            .map(|&e| material.mu(e))
            .collect::<Result<_>>()?;
        Ok(d.solve(&target))
    }
}

/// The scene's true basis fractions: each material's fractions spread over the basis by its
/// [`Basis::equivalent`] over `energies` (a material outside the basis, e.g. fat against water,
/// bone and iodine, keeps the part of its attenuation the basis cannot express).
pub fn basis_truth(
    maps: &crate::scene::MaterialMaps,
    basis: &Basis,
    energies: &[f64],
) -> Result<Vec<Array3<f32>>> {
    let (_, z, y, x) = maps.fractions.dim();
    let mut out = vec![Array3::<f32>::zeros((z, y, x)); basis.materials.len()];
    for (m, f) in maps.materials.iter().zip(maps.fractions.outer_iter()) {
        for (o, a) in out.iter_mut().zip(basis.equivalent(*m, energies)?) {
            o.scaled_add(a as f32, &f);
        }
    }
    Ok(out)
}

/// The true monoenergetic image at `kev` (mm⁻¹): `Σ_m μ_m(E)·f_m` over the scene's materials.
pub fn true_vmi(maps: &crate::scene::MaterialMaps, kev: f64) -> Result<Array3<f32>> {
    let (_, z, y, x) = maps.fractions.dim();
    let mut out = Array3::<f32>::zeros((z, y, x));
    for (m, f) in maps.materials.iter().zip(maps.fractions.outer_iter()) {
        out.scaled_add(m.mu(kev)? as f32, &f);
    }
    Ok(out)
}

/// How well the channels separate the basis (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Separability {
    /// Condition number of the channel matrix with unit-norm columns.
    pub condition: f64,
    /// Per basis material: standard deviation of its fraction per mm⁻¹ of channel noise.
    pub noise_gain: Vec<f64>,
}

/// Least squares restricted to a subset of the basis: the subset and its pseudo-inverse
/// `(A_Sᵀ A_S)⁻¹ A_Sᵀ` (`[|S|][channel]`).
struct Subset {
    members: Vec<usize>,
    pinv: Vec<Vec<f64>>,
}

/// A basis decomposition prepared for a set of channels.
pub struct Decomposition {
    basis: Basis,
    /// `[channel][basis]`, mm⁻¹.
    matrix: Vec<Vec<f64>>,
    subsets: Vec<Subset>,
    pub separability: Separability,
}

impl Decomposition {
    /// The decomposition of `channels` onto `basis`; refused (naming the most alike pair) when
    /// the channels cannot separate the basis.
    pub fn new(basis: Basis, channels: &[ChannelSpec]) -> Result<Decomposition> {
        let (c, b) = (channels.len(), basis.materials.len());
        if c < b {
            return Err(Error::invalid(
                "basis",
                format!(
                    "{b} basis materials need at least {b} channels, the scene has {c}: a \
                     decomposition would be underdetermined"
                ),
            ));
        }
        let matrix: Vec<Vec<f64>> = channels
            .iter()
            .enumerate()
            .map(|(i, s)| {
                basis
                    .materials
                    .iter()
                    .map(|&m| s.effective_mu(m))
                    .collect::<Result<Vec<_>>>()
                    .map_err(|e| e.under(&format!("channels[{i}]")))
            })
            .collect::<Result<_>>()?;
        let gram = gram(&matrix, &(0..b).collect::<Vec<_>>());
        let norms: Vec<f64> = (0..b).map(|j| gram[j][j].sqrt()).collect();
        let unit: Vec<Vec<f64>> = (0..b)
            .map(|i| (0..b).map(|j| gram[i][j] / (norms[i] * norms[j])).collect())
            .collect();
        let eig = symmetric_eigenvalues(unit);
        let (lo, hi) = eig
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(l, h), &e| (l.min(e), h.max(e)));
        let condition = if lo > 0.0 {
            (hi / lo).sqrt()
        } else {
            f64::INFINITY
        };
        if condition.is_nan() || condition > MAX_CONDITION {
            let (i, j) = most_alike(&gram, &norms);
            return Err(Error::invalid(
                "basis",
                format!(
                    "the channels cannot separate {} from {} (condition number {condition:.3e} > \
                     {MAX_CONDITION}): their attenuation is nearly proportional across the \
                     channels; use channels on both sides of an absorption edge or wider apart, \
                     or fewer basis materials",
                    basis.materials[i].name(),
                    basis.materials[j].name()
                ),
            ));
        }
        let inverse = invert(&gram).expect("a well-conditioned Gram matrix is invertible");
        let noise_gain = (0..b).map(|k| inverse[k][k].sqrt()).collect();
        let subsets = (1..1usize << b)
            .filter_map(|mask| {
                let members: Vec<usize> = (0..b).filter(|k| mask & (1 << k) != 0).collect();
                let inv = invert(&gram_of(&gram, &members))?;
                let pinv = (0..members.len())
                    .map(|r| {
                        (0..c)
                            .map(|ch| {
                                members
                                    .iter()
                                    .enumerate()
                                    .map(|(k, &col)| inv[r][k] * matrix[ch][col])
                                    .sum()
                            })
                            .collect()
                    })
                    .collect();
                Some(Subset { members, pinv })
            })
            .collect();
        Ok(Decomposition {
            basis,
            matrix,
            subsets,
            separability: Separability {
                condition,
                noise_gain,
            },
        })
    }

    pub fn basis(&self) -> &Basis {
        &self.basis
    }

    /// The channel matrix `[channel][basis]`, mm⁻¹.
    pub fn matrix(&self) -> &[Vec<f64>] {
        &self.matrix
    }

    /// The non-negative fractions that best explain one voxel's channel values `mu` (mm⁻¹) in
    /// least squares: the best of the unconstrained solutions on every subset of the basis that
    /// come out non-negative (exact for this small a basis: the optimum is the unconstrained
    /// solution on its own support). A voxel of air (or all channels ≤ 0) gives zeros.
    pub fn solve(&self, mu: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.basis.materials.len()];
        self.solve_into(mu, &mut out);
        out
    }

    /// [`Decomposition::solve`] into `out` (one entry per basis material), without allocating.
    fn solve_into(&self, mu: &[f64], out: &mut [f64]) {
        let b = out.len();
        out.fill(0.0);
        let mut best_r = mu.iter().map(|v| v * v).sum::<f64>();
        let mut x = [0.0; MAX_BASIS];
        for s in &self.subsets {
            x.fill(0.0);
            let mut feasible = true;
            for (row, &col) in s.pinv.iter().zip(&s.members) {
                let v: f64 = row.iter().zip(mu).map(|(p, m)| p * m).sum();
                feasible &= v >= 0.0;
                x[col] = v;
            }
            if !feasible {
                continue;
            }
            let r: f64 = self
                .matrix
                .iter()
                .zip(mu)
                .map(|(a, m)| (a.iter().zip(&x).map(|(a, x)| a * x).sum::<f64>() - m).powi(2))
                .sum();
            if r < best_r {
                best_r = r;
                out.copy_from_slice(&x[..b]);
            }
        }
    }

    /// Fraction volumes (one per basis material, `[z][y][x]`) from one volume per channel
    /// (mm⁻¹, all of one shape).
    pub fn volumes(&self, channels: &[ArrayView3<f32>]) -> Result<Vec<Array3<f32>>> {
        if channels.len() != self.matrix.len() {
            return Err(Error::invalid(
                "volumes",
                format!(
                    "{} volumes for {} channels",
                    channels.len(),
                    self.matrix.len()
                ),
            ));
        }
        let shape = channels[0].dim();
        if let Some(i) = channels.iter().position(|v| v.dim() != shape) {
            return Err(Error::invalid(
                format!("volumes[{i}]"),
                format!(
                    "shape {:?}, the first volume's is {shape:?}",
                    channels[i].dim()
                ),
            ));
        }
        // Borrowed when already in standard layout (a run's volumes are).
        let flat: Vec<_> = channels.iter().map(|v| v.as_standard_layout()).collect();
        let flat: Vec<&[f32]> = flat
            .iter()
            .map(|v| v.as_slice().expect("standard layout"))
            .collect();
        let b = self.basis.materials.len();
        let n = flat[0].len();
        let mut out = vec![0.0f32; n * b];
        out.par_chunks_mut(b).enumerate().for_each_init(
            || (vec![0.0; flat.len()], [0.0; MAX_BASIS]),
            |(mu, x), (i, o)| {
                for (m, v) in mu.iter_mut().zip(&flat) {
                    *m = v[i] as f64;
                }
                self.solve_into(mu, &mut x[..b]);
                for (o, x) in o.iter_mut().zip(x.iter()) {
                    *o = *x as f32;
                }
            },
        );
        Ok((0..b)
            .map(|k| {
                let v: Vec<f32> = out.iter().skip(k).step_by(b).copied().collect();
                Array3::from_shape_vec(shape, v).expect("one value per voxel")
            })
            .collect())
    }
}

/// Whether a VMI at `kev` extrapolates the basis model: `kev` outside the channels' centre
/// energies `channel_kev` ([`ChannelSpec::mean_kev`]).
pub fn extrapolates(channel_kev: &[f64], kev: f64) -> bool {
    let lo = channel_kev.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = channel_kev
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    !(lo..=hi).contains(&kev)
}

/// The virtual monoenergetic image at `kev` (mm⁻¹): `Σ_b ρ_b·μ_b(E)` over the basis fractions.
pub fn vmi(basis: &Basis, fractions: &[Array3<f32>], kev: f64) -> Result<Array3<f32>> {
    let mu = basis.mu(kev)?;
    if fractions.len() != mu.len() || fractions.is_empty() {
        return Err(Error::invalid(
            "fractions",
            format!(
                "{} fraction volumes for {} basis materials",
                fractions.len(),
                mu.len()
            ),
        ));
    }
    let mut out = Array3::<f32>::zeros(fractions[0].dim());
    for (f, m) in fractions.iter().zip(mu) {
        out.scaled_add(m as f32, f);
    }
    Ok(out)
}

/// `AᵀA` restricted to the columns `cols`.
fn gram(a: &[Vec<f64>], cols: &[usize]) -> Vec<Vec<f64>> {
    cols.iter()
        .map(|&i| {
            cols.iter()
                .map(|&j| a.iter().map(|row| row[i] * row[j]).sum())
                .collect()
        })
        .collect()
}

/// The sub-matrix of `g` on `members`.
fn gram_of(g: &[Vec<f64>], members: &[usize]) -> Vec<Vec<f64>> {
    members
        .iter()
        .map(|&i| members.iter().map(|&j| g[i][j]).collect())
        .collect()
}

/// The pair of basis columns with the largest |cosine| between them.
fn most_alike(g: &[Vec<f64>], norms: &[f64]) -> (usize, usize) {
    let mut best = (0, 0, -1.0f64);
    for i in 0..g.len() {
        for j in i + 1..g.len() {
            let c = (g[i][j] / (norms[i] * norms[j])).abs();
            if c > best.2 {
                best = (i, j, c);
            }
        }
    }
    (best.0, best.1)
}

/// Inverse of a small matrix by Gauss–Jordan elimination with partial pivoting; `None` when a
/// pivot vanishes relative to the matrix's scale.
fn invert(m: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = m.len();
    let scale = m.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return None;
    }
    let mut a: Vec<Vec<f64>> = m
        .iter()
        .enumerate()
        .map(|(i, row)| {
            let mut r = row.clone();
            r.extend((0..n).map(|j| f64::from(u8::from(i == j))));
            r
        })
        .collect();
    for col in 0..n {
        let p = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[p][col].abs() <= 1e-14 * scale {
            return None;
        }
        a.swap(col, p);
        let d = a[col][col];
        a[col].iter_mut().for_each(|v| *v /= d);
        for r in 0..n {
            if r != col {
                let f = a[r][col];
                let pivot = a[col].clone();
                a[r].iter_mut().zip(&pivot).for_each(|(v, p)| *v -= f * p);
            }
        }
    }
    Some(a.into_iter().map(|r| r[n..].to_vec()).collect())
}

/// Eigenvalues of a small symmetric matrix (cyclic Jacobi rotations to 1e-15 off-diagonal).
fn symmetric_eigenvalues(mut a: Vec<Vec<f64>>) -> Vec<f64> {
    let n = a.len();
    for _ in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let (c, s) = (1.0 / (t * t + 1.0).sqrt(), t / (t * t + 1.0).sqrt());
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (rp, rq) = (a[p].clone(), a[q].clone());
                for (k, (apk, aqk)) in rp.into_iter().zip(rq).enumerate() {
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
            }
        }
    }
    (0..n).map(|i| a[i][i]).collect()
}

/// How a scene's channels were formed: the simulator's channel descriptions when its provenance
/// records them (exact), else from the spectral coordinates (a mono channel is exact; a tube
/// voltage or a mixing is taken with the default filtration, and the second value says so); a
/// photon-counting window without its tube voltage is refused.
pub fn channel_specs(scene: &crate::scene::Scene) -> Result<(Vec<ChannelSpec>, bool)> {
    #[derive(serde::Deserialize)]
    struct Recorded {
        channels: Vec<ChannelSpec>,
    }
    if let Ok(r) = serde_yaml_ng::from_str::<Recorded>(&scene.provenance.config)
        && r.channels.len() == scene.n_channels()
    {
        return Ok((r.channels, true));
    }
    use crate::scene::SpectralCoordinate as C;
    let mut exact = true;
    let specs = scene
        .channels
        .iter()
        .enumerate()
        .map(|(i, ch)| match ch.coordinate {
            C::Energy { kev } => Ok(ChannelSpec::Mono { kev }),
            C::TubeVoltage { kvp } => {
                exact = false;
                Ok(ChannelSpec::Polychromatic {
                    kvp: kvp.round() as u32,
                    filtration: Default::default(),
                })
            }
            C::Mixing {
                lambda,
                low_kvp,
                high_kvp,
            } => {
                exact = false;
                Ok(ChannelSpec::Mixed {
                    lambda,
                    low_kvp: low_kvp.round() as u32,
                    high_kvp: high_kvp.round() as u32,
                    filtration: Default::default(),
                })
            }
            C::Window { .. } | C::Unspecified => Err(Error::invalid(
                format!("channels[{i}].coordinate"),
                format!(
                    "channel `{}`: its spectrum is not recorded in the scene (a window needs its \
                     tube voltage), so its basis attenuation is unknown",
                    ch.label
                ),
            )),
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((specs, exact))
}
