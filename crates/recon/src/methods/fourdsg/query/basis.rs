//! The material model of a basis-head run (`stage2.basis`): `basis.safetensors` beside the run's
//! `gaussians.safetensors`, read back as [`BasisModel`] for material maps and monoenergetic
//! images at any energy of the attenuation table (10–150 keV).
//!
//! Format `prism-basis/1`: the f32 tensor `densities_raw [K, B]` (the Gaussians' raw basis
//! columns, same Gaussians and order as the model file; see [`crate::methods::fourdsg::heads::basis`] for their
//! units) and the string metadata `format` and `basis` (JSON: `materials`, `reference_mu`
//! (μ̂_b, mm⁻¹) and `channel_kev` (each trained channel's centre energy, keV)).

use crate::device::{host_values, upload};
use crate::gaussians::io::{LoadedModel, load_model};
use crate::gaussians::model::GaussianModel;
use crate::gaussians::volume::volumes_with;
use crate::methods::fourdsg::heads::BasisHead;
use crate::methods::fourdsg::heads::basis::mix_raw;
use crate::record::tensors::{TensorFile, Tensors};
use crate::{Error, Result};
use burn::tensor::{Device, Tensor};
use ndarray::{Array3, Axis};
use prism_domain::physics::Material;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// File name in a run directory.
pub const BASIS_FILE: &str = "basis.safetensors";
const FORMAT: &str = "prism-basis/1";

/// The `basis` metadata.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BasisMeta {
    pub materials: Vec<Material>,
    /// μ̂_b per material, mm⁻¹.
    pub reference_mu: Vec<f64>,
    /// Centre energy of every trained channel, keV.
    pub channel_kev: Vec<f64>,
}

/// Write the basis columns of `model` (trained with `head`) to `path`.
pub fn save_basis(path: &Path, head: &BasisHead, model: &GaussianModel) -> Result<()> {
    let meta = BasisMeta {
        materials: head.basis().materials().to_vec(),
        reference_mu: head.reference_mu().to_vec(),
        channel_kev: head.channel_kev().to_vec(),
    };
    let raw = host_values(&model.densities.value);
    let mut tensors = Tensors::default();
    tensors.f32("densities_raw", &raw, [model.len(), meta.materials.len()]);
    let meta: HashMap<String, String> = [
        ("format".to_string(), FORMAT.to_string()),
        (
            "basis".to_string(),
            serde_json::to_string(&meta).expect("basis metadata serialises"),
        ),
    ]
    .into();
    tensors.write(path, meta)
}

/// A basis-head run's Gaussians with their material densities.
pub struct BasisModel {
    pub loaded: LoadedModel,
    pub meta: BasisMeta,
    /// Raw basis columns `[K, B]`.
    raw: Tensor<2>,
}

impl BasisModel {
    /// The material model beside the spectral model file `model` (a run directory's
    /// `gaussians.safetensors`), or `None` when there is no [`BASIS_FILE`] beside it (a run
    /// without the basis head, or no spectral run at all). A model trained with the basis head
    /// whose file is gone is an error: without it a monoenergetic query would answer another
    /// quantity (the curve's interpolation).
    pub fn open(model: &Path, device: &Device) -> Result<Option<BasisModel>> {
        let path = model.with_file_name(BASIS_FILE);
        if !model.exists() {
            return Ok(None);
        }
        let loaded = load_model(model, device)?;
        if !path.exists() {
            if loaded.info.basis {
                return Err(Error::field(
                    &path,
                    ".",
                    format!(
                        "missing: {} was trained with a basis head, whose materials this file \
                         holds; monoenergetic images need it",
                        model.display()
                    ),
                ));
            }
            return Ok(None);
        }
        let f = TensorFile::open(&path, FORMAT)?;
        let meta: BasisMeta = f.json("basis")?;
        let b = meta.materials.len();
        let bad =
            |field: &str, why: String| Error::field(&path, format!("metadata.basis.{field}"), why);
        if b == 0 || meta.reference_mu.len() != b {
            return Err(bad(
                "reference_mu",
                format!("{} values for {b} materials", meta.reference_mu.len()),
            ));
        }
        if let Some(r) = meta
            .reference_mu
            .iter()
            .find(|r| !(r.is_finite() && **r > 0.0))
        {
            return Err(bad(
                "reference_mu",
                format!("{r} is not a positive attenuation"),
            ));
        }
        let raw = f.rows("densities_raw", b)?;
        if raw.len() != loaded.model.len() * b {
            return Err(Error::field(
                &path,
                "densities_raw",
                format!(
                    "{} Gaussians, the model file has {}",
                    raw.len() / b,
                    loaded.model.len()
                ),
            ));
        }
        if let Some(i) = raw.iter().position(|v| v.is_nan()) {
            return Err(Error::field(
                &path,
                "densities_raw",
                format!("NaN at Gaussian {}", i / b),
            ));
        }
        Ok(Some(BasisModel {
            raw: upload(raw, b, device),
            loaded,
            meta,
        }))
    }

    /// Volume fraction of every basis material (`[z][y][x]` each, at its nominal density) on the
    /// run's grid.
    pub fn fractions(&self) -> Result<Vec<Array3<f32>>> {
        let l = &self.loaded;
        let v = volumes_with(
            &l.model,
            self.raw.clone(),
            &l.info.geometry.volume,
            &l.world,
        )?;
        Ok(v.outer_iter()
            .zip(&self.meta.reference_mu)
            .map(|(f, r)| f.mapv(|x| (x as f64 / r) as f32))
            .collect())
    }

    /// Raw densities `[K, 1]` of the monoenergetic attenuation at `kev`: `Σ_b v_b·μ_b(E)/μ̂_b`.
    /// Errors name `kev` outside the attenuation table.
    pub fn vmi_raw(&self, kev: f64) -> Result<Tensor<2>> {
        let coef: Vec<f64> = self
            .meta
            .materials
            .iter()
            .zip(&self.meta.reference_mu)
            .map(|(m, r)| Ok(m.mu(kev)? / r))
            .collect::<Result<_>>()
            .map_err(|e| e.under("kev"))?;
        Ok(mix_raw(&self.raw, |v, out| {
            out.push(v.iter().zip(&coef).map(|(v, c)| v * c).sum());
        }))
    }

    /// The monoenergetic image at `kev` (μ, mm⁻¹) on the run's grid: `Σ_b f_b·μ_b(E)`.
    pub fn vmi(&self, kev: f64) -> Result<Array3<f32>> {
        let l = &self.loaded;
        Ok(volumes_with(
            &l.model,
            self.vmi_raw(kev)?,
            &l.info.geometry.volume,
            &l.world,
        )?
        .index_axis(Axis(0), 0)
        .to_owned())
    }

    /// Line integrals `[view][row][col]` of the monoenergetic attenuation at `kev` at every
    /// view of the run's geometry.
    pub fn vmi_projections(&self, kev: f64) -> Result<Array3<f32>> {
        let l = &self.loaded;
        let views: Vec<usize> = (0..l.info.geometry.views()).collect();
        crate::gaussians::volume::render_views(
            &l.model,
            self.vmi_raw(kev)?,
            &l.world,
            &l.info.geometry,
            &views,
            &l.info.projection.options(),
        )
    }

    /// Whether `kev` lies outside the trained channels' centre energies (an extrapolation of
    /// the basis model).
    pub fn extrapolates(&self, kev: f64) -> bool {
        prism_domain::decompose::extrapolates(&self.meta.channel_kev, kev)
    }
}
