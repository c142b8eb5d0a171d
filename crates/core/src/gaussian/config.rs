//! Configuration of the Gaussian methods (YAML), every hyperparameter with its default.

use super::densify::DensifyConfig;
use super::host::ScaleBounds;
use super::init::InitConfig;
use super::trainer::{LearningRates, LossConfig};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The Gaussian reconstruction methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GaussianMethod {
    /// R²-Gaussian, every channel reconstructed independently.
    #[serde(rename = "r2gs")]
    R2gs,
    /// 4D-SG stage 1: shared geometry from the structural projections, then per-channel densities
    /// fitted directly on the fixed geometry (no curve model).
    #[serde(rename = "4dsg-stage1")]
    Stage1,
}

impl GaussianMethod {
    pub fn name(self) -> &'static str {
        match self {
            GaussianMethod::R2gs => "r2gs",
            GaussianMethod::Stage1 => "4dsg-stage1",
        }
    }
}

/// Where stage 1's structural projection comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StructuralSource {
    /// The scene's measured full-spectrum projection when it has one, else `mean`.
    #[default]
    Auto,
    /// Mean over the channels at each view (conventional spectral CT); views where a channel is
    /// missing are left out of the structural stage.
    Mean,
    /// The scene's measured full-spectrum projection (photon-counting); an error if absent.
    Provided,
}

/// A Gaussian method's configuration. Lengths are in the normalised world (the volume's largest
/// edge spans 2), densities in units of the FDK's 99.9th percentile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GaussianConfig {
    pub method: GaussianMethod,
    #[serde(default)]
    pub seed: u64,
    /// Iterations of the geometry stage (per channel for `r2gs`; upstream 30 000).
    #[serde(default = "default_iterations")]
    pub iterations: usize,
    /// `4dsg-stage1`: iterations of the per-channel density fit on the fixed geometry.
    #[serde(default = "default_density_iterations")]
    pub density_iterations: usize,
    #[serde(default = "default_init")]
    pub init: InitConfig,
    /// Scale activation bounds as fractions of the normalised volume extent (upstream 0.0005,
    /// 0.5, i.e. 0.001 and 1.0 in normalised units).
    #[serde(default = "default_bounds")]
    pub scale_bounds: ScaleBounds,
    #[serde(default)]
    pub lr: LearningRates,
    #[serde(default)]
    pub loss: LossConfig,
    /// Adaptive density control; `null` turns it off.
    #[serde(default = "default_densify")]
    pub densify: Option<DensifyConfig>,
    /// Evaluate (voxelize, PSNR/SSIM) every this many iterations; 0: only at the end of a stage.
    #[serde(default = "default_eval_every")]
    pub eval_every: usize,
    #[serde(default)]
    pub structural: StructuralSource,
}

fn default_iterations() -> usize {
    3000
}
fn default_density_iterations() -> usize {
    1000
}
fn default_init() -> InitConfig {
    InitConfig {
        n_points: 20_000,
        ..InitConfig::default()
    }
}
fn default_bounds() -> ScaleBounds {
    ScaleBounds {
        min: 0.0005,
        max: 0.5,
    }
}
fn default_densify() -> Option<DensifyConfig> {
    Some(DensifyConfig {
        from: 100,
        until: 1500,
        ..DensifyConfig::default()
    })
}
fn default_eval_every() -> usize {
    250
}

impl GaussianConfig {
    /// A configuration for `method` with every default.
    pub fn new(method: GaussianMethod) -> Self {
        GaussianConfig {
            method,
            seed: 0,
            iterations: default_iterations(),
            density_iterations: default_density_iterations(),
            init: default_init(),
            scale_bounds: default_bounds(),
            lr: LearningRates::default(),
            loss: LossConfig::default(),
            densify: default_densify(),
            eval_every: default_eval_every(),
            structural: StructuralSource::Auto,
        }
    }

    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let cfg: GaussianConfig =
            serde_yaml_ng::from_str(text).map_err(|e| crate::yaml::error(file, &e))?;
        cfg.validate().map_err(|e| e.in_file(file))?;
        Ok(cfg)
    }

    /// Scale bounds in normalised length units (the extent is 2).
    pub fn bounds(&self) -> ScaleBounds {
        ScaleBounds {
            min: 2.0 * self.scale_bounds.min,
            max: 2.0 * self.scale_bounds.max,
        }
    }

    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::invalid("iterations", "must be at least 1"));
        }
        if self.method == GaussianMethod::Stage1 && self.density_iterations == 0 {
            return Err(Error::invalid("density_iterations", "must be at least 1"));
        }
        self.init.validate()?;
        self.scale_bounds.validate()?;
        self.lr.validate()?;
        self.loss.validate()?;
        if let Some(d) = &self.densify {
            d.validate()?;
        }
        Ok(())
    }
}
