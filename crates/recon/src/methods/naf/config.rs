//! NAF's run configuration (`configs/recon/naf.yaml`).

use crate::device::DeviceChoice;
use crate::{Error, Result};
use prism_domain::error::ensure_positive;
use prism_field::FieldConfig;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The one method of this family (the YAML's `method: naf`; the name: [`crate::Method`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "crate::Method", into = "crate::Method")]
pub enum NafMethod {
    #[default]
    Naf,
}

/// A step-decayed learning rate (PyTorch's `StepLR`): `init · gamma^⌊t / every⌋` at iteration t
/// (0-based).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepDecay {
    pub init: f64,
    pub gamma: f64,
    pub every: usize,
}

impl StepDecay {
    pub fn at(&self, t: usize) -> f64 {
        self.init * self.gamma.powi((t / self.every.max(1)) as i32)
    }
}

/// NAF per channel: a hash-grid field fitted to the channel's line integrals.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NafConfig {
    pub method: NafMethod,
    pub seed: u64,
    pub device: DeviceChoice,
    /// Iterations per channel (one view's rays each).
    pub iterations: usize,
    /// Rays drawn (without replacement) from one training view per iteration.
    pub rays_per_batch: usize,
    /// Stratified samples along each ray's chord through the volume box.
    pub samples_per_ray: usize,
    /// Adam's learning rate (β 0.9, 0.999, ε 1e-8) and its step decay.
    pub lr: StepDecay,
    /// The field's output is `sigmoid · attenuation_range · u`, u the 99.9th percentile of the
    /// positive values of an FDK of the training views (mm⁻¹).
    pub attenuation_range: f64,
    pub field: FieldConfig,
    /// Score the volume (when the scene has references) every this many iterations.
    pub eval_every: usize,
    /// Save the run's state for `prism recon --resume` every this many iterations
    /// ([`super::resume`]); 0: only when the run is interrupted.
    pub checkpoint_every: usize,
}

impl Default for NafConfig {
    fn default() -> Self {
        NafConfig {
            method: NafMethod::Naf,
            seed: 0,
            device: DeviceChoice::default(),
            iterations: 1500,
            rays_per_batch: 1024,
            samples_per_ray: 96,
            lr: StepDecay {
                init: 1e-3,
                gamma: 0.1,
                every: 1500,
            },
            attenuation_range: 2.0,
            field: FieldConfig::default(),
            eval_every: 250,
            checkpoint_every: 0,
        }
    }
}

impl NafConfig {
    /// Parse YAML text; errors name `file` and the field.
    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let cfg: NafConfig =
            serde_yaml_ng::from_str(text).map_err(|e| prism_domain::yaml::error(file, &e))?;
        cfg.validate().map_err(|e| e.in_file(file))?;
        Ok(cfg)
    }

    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("iterations", self.iterations),
            ("rays_per_batch", self.rays_per_batch),
            ("samples_per_ray", self.samples_per_ray),
            ("lr.every", self.lr.every),
            ("eval_every", self.eval_every),
        ] {
            if v == 0 {
                return Err(Error::invalid(name, "must be at least 1"));
            }
        }
        if self.rays_per_batch * self.samples_per_ray > 1 << 24 {
            return Err(Error::invalid(
                "rays_per_batch",
                "rays_per_batch × samples_per_ray exceeds 2^24 points per batch",
            ));
        }
        ensure_positive("lr.init", self.lr.init)?;
        ensure_positive("lr.gamma", self.lr.gamma)?;
        ensure_positive("attenuation_range", self.attenuation_range)?;
        Ok(self.field.validate("field")?)
    }
}
