//! One gated spectral SSM block (paper eq. `gscnet_backbone`), stackable:
//!
//! ```text
//! X' = LayerNorm(X + Φ_post( Φ_ssm(Φ_conv(X)) ⊙ Φ_gate(X) ))
//! Φ_conv(X) = SiLU(depthwise_conv_m(X W_in))     centred kernel over neighbouring channels
//! Φ_gate(X) = SiLU(X W_gate)
//! Φ_ssm     = selective scan along m (see [`crate::ssm`])
//! Φ_post    = linear output projection
//! ```
//!
//! Tokens are `[K, M, d]` (Gaussians × channels × width); every operation is batched over K.

use crate::init::SeedStream;
use burn::module::Module;
use burn::nn::conv::Conv1d;
use burn::nn::{LayerNorm, LayerNormConfig, Linear};
use burn::tensor::{Device, Tensor};

use crate::conv::spectral_conv_silu;
use crate::init::{self, apply_rows};
use crate::ops::silu;
use crate::ssm::SelectiveSsm;

/// A gated spectral SSM block with residual connection and post-normalisation.
#[derive(Module, Debug)]
pub struct SpectralBlock {
    pub in_proj: Linear,
    pub gate_proj: Linear,
    pub conv: Conv1d,
    pub ssm: SelectiveSsm,
    pub out_proj: Linear,
    pub norm: LayerNorm,
}

/// Sizes of one block.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BlockShape {
    pub width: usize,
    pub state: usize,
    pub kernel: usize,
    pub dt_min: f32,
    pub dt_max: f32,
}

impl SpectralBlock {
    pub(crate) fn new(rng: &mut SeedStream, s: BlockShape, device: &Device) -> Self {
        let d = s.width;
        Self {
            in_proj: init::linear(rng, d, d, true, 1.0, device),
            gate_proj: init::linear(rng, d, d, true, 1.0, device),
            conv: init::depthwise_conv1d(rng, d, s.kernel, device),
            ssm: SelectiveSsm::new(rng, d, s.state, s.dt_min, s.dt_max, device),
            out_proj: init::linear(rng, d, d, true, 1.0, device),
            norm: LayerNormConfig::new(d).init(device),
        }
    }

    /// `x` [K, M, d] → [K, M, d].
    pub fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        let u = spectral_conv_silu(apply_rows(&self.in_proj, x.clone()), &self.conv);
        let y = self.ssm.forward(u);
        let gated = y.mul(silu(apply_rows(&self.gate_proj, x.clone())));
        self.norm.forward(x.add(apply_rows(&self.out_proj, gated)))
    }
}
