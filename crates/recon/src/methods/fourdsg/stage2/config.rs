//! Stage 2 of `4dsg` (YAML `stage2:`): iterations, the spectral head (the curve model, or the
//! basis-material head), its loss and rate, and which groups stay fixed.

use crate::gaussians::Learnable;
use crate::gaussians::adam::LogLinear;
use crate::{Error, Result};
use prism_domain::decompose::Basis;
use prism_domain::error::ensure_non_negative;
use prism_domain::physics::Material;
use prism_gscnet::CurveModelConfig;
use serde::{Deserialize, Serialize};

/// Which parameter groups stay fixed in stage 2 (the paper's freezing strategies).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Freeze {
    pub position: bool,
    pub rotation: bool,
    pub scale: bool,
    /// The common raw density u⁽ᶜ⁾.
    pub density: bool,
}

impl Freeze {
    /// The paper's strategy (FFFL): geometry fixed, common densities learnable. The default is
    /// everything learnable (LLLL): measured best here (`prism ablate freeze`: +1.34 dB on
    /// phantom-3mono and +0.43 dB on chest-3mono over FFFL).
    pub const PAPER: Freeze = Freeze {
        position: true,
        rotation: true,
        scale: true,
        density: false,
    };

    pub fn learnable(&self) -> Learnable {
        Learnable {
            position: !self.position,
            rotation: !self.rotation,
            scale: !self.scale,
            density: !self.density,
        }
    }

    /// P/R/S/D as the paper writes them: L learnable, F frozen.
    pub fn code(&self) -> String {
        [self.position, self.rotation, self.scale, self.density]
            .iter()
            .map(|&frozen| if frozen { 'F' } else { 'L' })
            .collect()
    }
}

/// Stage 2 of `4dsg` (YAML `stage2:`; every field optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Stage2Config {
    /// Iterations (paper: 5000 after 30 000 of stage 1; default 1000: on chest-3mono, 500 → 1000
    /// gave +0.41 dB).
    pub iterations: usize,
    /// GSC-Net (`kind: gscnet`) or the direct MLP (`kind: mlp`) and their sizes.
    pub curve_model: CurveModelConfig,
    /// Weight of L_curve, the first-order smoothness of Δu along the spectral axis.
    pub lambda_curve: f64,
    /// Adam learning rate of the network (log-linear decay).
    pub lr_network: LogLinear,
    pub freeze: Freeze,
    /// Condition the network's density input on the stage-1 raw densities (centre: median,
    /// scale: half the 10–90 % range) instead of the fixed û = u/(s + |u|) (default true: the
    /// fixed form left the occupied raw densities in a fifth of û's range; measured on
    /// phantom-3mono 40.37 dB against 36.22 dB).
    pub condition_on_stage1: bool,
    /// The basis-material head in place of the curve model (`crate::methods::fourdsg::heads::basis`); absent:
    /// the curve model.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub basis: Option<BasisConfig>,
    /// A free raw-density residual per Gaussian and channel added to the curve model's
    /// prediction, held near zero by an L2 penalty; absent: none (the paper's model, every
    /// channel a function of the Gaussian's common density).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub residual: Option<ResidualConfig>,
}

/// `stage2.residual`: channel residuals r `[K, M]` on top of the curve model,
/// `u⁽ᵐ⁾ = u⁽ᶜ⁾ + Δu⁽ᵐ⁾ + r⁽ᵐ⁾`, penalised by `weight · mean(r²)`. They start at zero and
/// learn at the density's rate. A large weight gives the paper's model back; weight 0 frees
/// every channel's density on the shared geometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResidualConfig {
    /// Weight of the residuals' mean square (raw-density units, ≥ 0).
    pub weight: f64,
}

impl Default for Stage2Config {
    fn default() -> Self {
        Stage2Config {
            iterations: 1000,
            curve_model: CurveModelConfig::default(),
            lambda_curve: 0.01,
            lr_network: LogLinear {
                init: 1e-3,
                end: 1e-4,
            },
            freeze: Freeze::default(),
            condition_on_stage1: true,
            basis: None,
            residual: None,
        }
    }
}

impl Stage2Config {
    /// Check ranges; errors name the field under `stage2`.
    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::invalid("stage2.iterations", "must be at least 1"));
        }
        self.curve_model
            .validate()
            .map_err(|e| Error::invalid("stage2.curve_model", e.to_string()))?;
        ensure_non_negative("stage2.lambda_curve", self.lambda_curve)?;
        if let Some(r) = &self.residual {
            ensure_non_negative("stage2.residual.weight", r.weight)?;
            let clash = if self.basis.is_some() {
                Some(
                    "the basis head forms its channels from materials; it has no curve to add a residual to",
                )
            } else if self.freeze.density {
                Some("the residuals learn with the densities, which stage2.freeze.density fixes")
            } else {
                None
            };
            if let Some(why) = clash {
                return Err(Error::invalid("stage2.residual", why));
            }
        }
        if let Some(b) = &self.basis {
            b.validate("stage2")?;
            if self.freeze.density {
                return Err(Error::invalid(
                    "stage2.freeze.density",
                    "the basis head learns the Gaussians' material densities: they cannot be \
                     frozen",
                ));
            }
        }
        self.lr_network.validate("stage2.lr_network")
    }
}

/// `stage2.basis`: the basis-material head and its start (YAML; every field optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BasisConfig {
    /// Basis materials (1 to 4, distinct; names of the attenuation table).
    pub materials: Vec<Material>,
    /// Share of the stage-1 attenuation each material after the first starts with.
    pub init_share: f64,
}

impl Default for BasisConfig {
    fn default() -> Self {
        BasisConfig {
            materials: Basis::body().materials().to_vec(),
            init_share: 0.05,
        }
    }
}

impl BasisConfig {
    /// Check the basis and the start; errors name the field under `{section}.basis`
    /// (`stage2`, or `joint` for stage 1's joint fit).
    pub fn validate(&self, section: &str) -> Result<Basis> {
        let basis = Basis::new(&self.materials).map_err(|e| Error::from(e).under(section))?;
        let others = (self.materials.len() - 1) as f64;
        if !(self.init_share > 0.0 && self.init_share * others < 1.0) {
            return Err(Error::invalid(
                format!("{section}.basis.init_share"),
                format!(
                    "must be > 0 and leave the first material a positive share ({others} × {} ≥ 1)",
                    self.init_share
                ),
            ));
        }
        Ok(basis)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `stage2.residual` reads from YAML, and a negative weight, the basis head or frozen
    /// densities are refused naming the field.
    #[test]
    fn channel_residual_settings_are_checked() {
        let c: Stage2Config = serde_yaml_ng::from_str("residual: {weight: 0.1}").unwrap();
        assert_eq!(c.residual, Some(ResidualConfig { weight: 0.1 }));
        c.validate().unwrap();
        let bad = |c: Stage2Config, field: &str, why: &str| {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(field) && e.contains(why), "{e}");
        };
        let mut neg = c.clone();
        neg.residual = Some(ResidualConfig { weight: -1.0 });
        bad(neg, "stage2.residual.weight", "≥ 0");
        let mut basis = c.clone();
        basis.basis = Some(BasisConfig::default());
        bad(basis, "stage2.residual", "basis head");
        let mut frozen = c;
        frozen.freeze.density = true;
        bad(frozen, "stage2.residual", "freeze.density");
    }
}
