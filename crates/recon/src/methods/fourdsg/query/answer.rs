//! One query of a spectral run, whichever head it was trained with: the dispatch `prism query`
//! and the Python package (`prism.query`) share. A photon energy asks for a virtual
//! monoenergetic image: from the basis head where the run has one (at any energy of the
//! attenuation table, with a warning outside the trained channels' energies), else from the
//! curves when the run's channels are energies; a coordinate or τ asks the curves.

use super::{BasisModel, Query, QueryAt};
use crate::gaussians::io::LoadedModel;
use crate::{Error, Result};
use burn::tensor::Device;
use ndarray::Array3;
use std::path::Path;

/// Where on the spectral axis a query asks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Ask {
    /// A physical coordinate in the model's unit (keV, kVp, λ, …).
    Coordinate(f64),
    /// Normalised τ (0 and 1 are the first and last channel).
    Tau(f64),
    /// A photon energy in keV (a virtual monoenergetic image).
    Kev(f64),
}

/// A spectral run's trained model.
pub enum SpectralModel {
    /// The basis head (`stage2.basis`): material maps times their attenuation at any energy.
    Basis(BasisModel),
    /// Per-Gaussian density curves along the spectral axis.
    Curves(Query),
}

/// What a query gives: the volume `[z][y][x]` (mm⁻¹) or the projections `[view][row][col]`,
/// a warning when the answer extrapolates, and one line saying what was answered.
pub struct Answer {
    pub data: Array3<f32>,
    pub warning: Option<String>,
    pub summary: String,
}

impl SpectralModel {
    /// The model in `path` (a run directory's `RunDir::spectral_model`): its basis head when `ask`
    /// is a photon energy and the run has one, else its curves.
    pub fn open(path: &Path, ask: Ask, device: &Device) -> Result<Self> {
        if let Ask::Kev(_) = ask
            && let Some(b) = BasisModel::open(path, device)?
        {
            return Ok(SpectralModel::Basis(b));
        }
        Ok(SpectralModel::Curves(Query::open(path, device)?))
    }

    /// The model as loaded (its geometry, channels and Gaussians).
    pub fn loaded(&self) -> &LoadedModel {
        match self {
            SpectralModel::Basis(b) => &b.loaded,
            SpectralModel::Curves(q) => &q.loaded,
        }
    }

    /// Answer `ask` with the volume, or with the projections at every view of the run's
    /// geometry; `extrapolate` allows a coordinate outside the observed channels (curves).
    pub fn answer(&self, ask: Ask, projections: bool, extrapolate: bool) -> Result<Answer> {
        match (self, ask) {
            (SpectralModel::Basis(b), Ask::Kev(kev)) => {
                let data = if projections {
                    b.vmi_projections(kev)?
                } else {
                    b.vmi(kev)?
                };
                let warning = b.extrapolates(kev).then(|| {
                    format!(
                        "{kev} keV lies outside the trained channels' energies ({:?} keV): the \
                         image extrapolates the basis model, whose error grows with the distance",
                        b.meta.channel_kev
                    )
                });
                let names: Vec<&str> = b.meta.materials.iter().map(|m| m.name()).collect();
                let summary = format!("{kev} keV from the basis {}", names.join(", "));
                Ok(Answer {
                    data,
                    warning,
                    summary,
                })
            }
            (SpectralModel::Basis(_), _) => Err(Error::invalid(
                "kev",
                "a basis model opened for a photon energy answers photon energies (open the run \
                 again for a coordinate or τ: SpectralModel::open)",
            )),
            (SpectralModel::Curves(q), ask) => {
                let info = &q.loaded.info;
                let at = match ask {
                    Ask::Coordinate(c) => QueryAt::Coordinate(c),
                    Ask::Tau(t) => QueryAt::Tau(t),
                    Ask::Kev(kev) if info.monoenergetic => QueryAt::Coordinate(kev),
                    Ask::Kev(kev) => {
                        return Err(Error::invalid(
                            "kev",
                            format!(
                                "{kev} keV: this run has no basis head and its channels are not \
                                 all monoenergetic (axis in {}), so no coordinate is a photon \
                                 energy; train with stage2.basis for monoenergetic images, or \
                                 query a coordinate",
                                info.unit
                            ),
                        ));
                    }
                };
                let data = if projections {
                    q.projections(at, extrapolate)?
                } else {
                    q.volume(at, extrapolate)?
                };
                let observed = info
                    .channels
                    .iter()
                    .zip(&info.tau)
                    .map(|(l, t)| format!("{l} τ={t:.3}"))
                    .collect::<Vec<_>>()
                    .join(", ");
                let summary = format!("τ = {:.4} (observed: {observed})", q.tau(at));
                Ok(Answer {
                    data,
                    warning: None,
                    summary,
                })
            }
        }
    }
}
