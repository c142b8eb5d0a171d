//! Configuration of the spectral curve model (GSC-Net or the direct-MLP ablation).

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Which curve model maps (u^(c), τ) to Δu.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum CurveModelKind {
    /// GSC-Net: tokens along the spectral axis, gated selective-SSM blocks, curve head.
    #[default]
    Gscnet,
    /// Ablation: the same tokens decoded independently per (Gaussian, channel) by an MLP.
    Mlp,
}

impl CurveModelKind {
    /// The config spelling: `gscnet` or `mlp`.
    pub fn name(self) -> &'static str {
        match self {
            CurveModelKind::Gscnet => "gscnet",
            CurveModelKind::Mlp => "mlp",
        }
    }
}

/// Hyper-parameters of the curve model. Every field has a small default that runs on a CPU; a
/// YAML/JSON section may give any subset (`kind: mlp`, `width: 48`, …). Unknown keys are errors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CurveModelConfig {
    /// `gscnet` (default) or `mlp`.
    pub kind: CurveModelKind,
    /// Token width d (default 32).
    pub width: usize,
    /// SSM state size N per channel (default 8). GSC-Net only.
    pub state_size: usize,
    /// Rank R of the learnable spectral basis B ∈ R^{R×M} (default 3). GSC-Net only.
    pub rank: usize,
    /// GSC-Net: number of stacked SSM blocks; MLP: number of hidden layers (default 2).
    pub depth: usize,
    /// Number F of Fourier frequencies 2^k·π, k = 0..F, per scalar input (default 4, at most 12).
    pub fourier_frequencies: usize,
    /// Kernel size of the depthwise convolution over neighbouring channels; odd, centred, zero
    /// padded (default 3). GSC-Net only.
    pub conv_kernel: usize,
    /// Scale s of the raw-density conditioning û = u / (s + |u|) ∈ (−1, 1), in the units of the
    /// raw (pre-softplus) density (default 4: typical raw densities −8..4 map to −0.67..0.5, and
    /// |u| ~ 1e3 still gives finite, bounded features).
    pub u_scale: f32,
    /// Range of the initial SSM step Δ (log-uniform per channel; defaults 0.01..1, shorter than
    /// Mamba's 0.001..0.1 because spectral sequences have only 2–16 tokens).
    pub dt_min: f32,
    /// See `dt_min`.
    pub dt_max: f32,
    /// Evaluate the network on T nodes of the conditioned density û ∈ [−1, 1] (and one beyond
    /// each end) and interpolate to each Gaussian's û by cubic convolution (default 512). A
    /// Gaussian enters the network only through its common raw density (tokens
    /// γ_u(û_i) + γ_s(τ_m)), so this is the same curve up to the interpolation error
    /// O(h³·|Δu‴|) (slopes O(h²)), h = 2/(T − 1), at a cost independent of K. 0: evaluate the
    /// network once per Gaussian.
    pub table_size: usize,
}

impl Default for CurveModelConfig {
    fn default() -> Self {
        Self {
            kind: CurveModelKind::Gscnet,
            width: 32,
            state_size: 8,
            rank: 3,
            depth: 2,
            fourier_frequencies: 4,
            conv_kernel: 3,
            u_scale: 4.0,
            dt_min: 0.01,
            dt_max: 1.0,
            table_size: 512,
        }
    }
}

/// Largest accepted `fourier_frequencies`: 2^12·π·|x| with |x| ≤ 1 keeps the f32 phase error
/// below ~1e-3 rad.
pub const MAX_FOURIER_FREQUENCIES: usize = 12;

impl CurveModelConfig {
    /// Check every field; errors name the field.
    pub fn validate(&self) -> Result<()> {
        let at_least_one = |name: &str, v: usize| {
            if v == 0 {
                Err(Error::invalid(name, "must be at least 1"))
            } else {
                Ok(())
            }
        };
        at_least_one("width", self.width)?;
        at_least_one("state_size", self.state_size)?;
        at_least_one("rank", self.rank)?;
        at_least_one("depth", self.depth)?;
        if self.fourier_frequencies > MAX_FOURIER_FREQUENCIES {
            return Err(Error::invalid(
                "fourier_frequencies",
                format!(
                    "{} exceeds {MAX_FOURIER_FREQUENCIES} (the highest frequency would lose f32 phase precision)",
                    self.fourier_frequencies
                ),
            ));
        }
        if self.conv_kernel == 0 || self.conv_kernel.is_multiple_of(2) {
            return Err(Error::invalid(
                "conv_kernel",
                format!(
                    "{} must be odd and ≥ 1 (a centred kernel over neighbouring channels)",
                    self.conv_kernel
                ),
            ));
        }
        if !(self.u_scale.is_finite() && self.u_scale > 0.0) {
            return Err(Error::invalid(
                "u_scale",
                format!("{} must be finite and > 0", self.u_scale),
            ));
        }
        if !(self.dt_min.is_finite() && self.dt_min > 0.0) {
            return Err(Error::invalid(
                "dt_min",
                format!("{} must be finite and > 0", self.dt_min),
            ));
        }
        if !(self.dt_max.is_finite() && self.dt_max >= self.dt_min) {
            return Err(Error::invalid(
                "dt_max",
                format!(
                    "{} must be finite and ≥ dt_min = {}",
                    self.dt_max, self.dt_min
                ),
            ));
        }
        if self.table_size == 1 {
            return Err(Error::invalid(
                "table_size",
                "1 node cannot interpolate: use 0 (per-Gaussian evaluation) or ≥ 2",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_partial_sections_parse() {
        CurveModelConfig::default().validate().unwrap();
        let c: CurveModelConfig = serde_json::from_str(r#"{"kind": "mlp", "width": 16}"#).unwrap();
        assert_eq!(c.kind, CurveModelKind::Mlp);
        assert_eq!(c.width, 16);
        assert_eq!(c.rank, CurveModelConfig::default().rank);
        let c: CurveModelConfig = serde_json::from_str(r#"{"kind": "gscnet"}"#).unwrap();
        assert_eq!(c.kind, CurveModelKind::Gscnet);
        assert!(serde_json::from_str::<CurveModelConfig>(r#"{"widht": 16}"#).is_err());
        assert!(serde_json::from_str::<CurveModelConfig>(r#"{"kind": "mamba"}"#).is_err());
    }

    #[test]
    fn invalid_fields_are_named() {
        let field = |c: CurveModelConfig| c.validate().unwrap_err().field().to_string();
        let d = CurveModelConfig::default;
        assert_eq!(field(CurveModelConfig { width: 0, ..d() }), "width");
        assert_eq!(
            field(CurveModelConfig {
                state_size: 0,
                ..d()
            }),
            "state_size"
        );
        assert_eq!(field(CurveModelConfig { rank: 0, ..d() }), "rank");
        assert_eq!(field(CurveModelConfig { depth: 0, ..d() }), "depth");
        assert_eq!(
            field(CurveModelConfig {
                conv_kernel: 4,
                ..d()
            }),
            "conv_kernel"
        );
        assert_eq!(
            field(CurveModelConfig {
                fourier_frequencies: 13,
                ..d()
            }),
            "fourier_frequencies"
        );
        assert_eq!(
            field(CurveModelConfig {
                u_scale: 0.0,
                ..d()
            }),
            "u_scale"
        );
        assert_eq!(
            field(CurveModelConfig {
                dt_min: f32::NAN,
                ..d()
            }),
            "dt_min"
        );
        assert_eq!(
            field(CurveModelConfig {
                dt_max: 0.001,
                ..d()
            }),
            "dt_max"
        );
        assert_eq!(
            field(CurveModelConfig {
                table_size: 1,
                ..d()
            }),
            "table_size"
        );
    }
}
