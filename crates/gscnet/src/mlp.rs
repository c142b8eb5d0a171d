//! The direct-MLP ablation: the same tokens x_{i,m} = γ_u(u_i) + γ_s(τ_m) as GSC-Net, decoded
//! independently for each (Gaussian, channel) by `depth` hidden layers (linear → SiLU) and a
//! linear output. No sequence model, no pooling, no spectral basis: channels interact only
//! through the shared weights.

use crate::init::SeedStream;
use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::{Device, Tensor};

use crate::config::CurveModelConfig;
use crate::head::OUTPUT_GAIN;
use crate::init;
use crate::ops::silu;
use crate::tokenizer::Tokenizer;

/// Per-token MLP curve model.
#[derive(Module, Debug)]
pub struct CurveMlp {
    pub tokenizer: Tokenizer,
    pub hidden: Vec<Linear>,
    pub out: Linear,
}

impl CurveMlp {
    pub(crate) fn new(rng: &mut SeedStream, config: &CurveModelConfig, device: &Device) -> Self {
        let d = config.width;
        Self {
            tokenizer: Tokenizer::new(rng, d, config.fourier_frequencies, config.u_scale, device),
            hidden: (0..config.depth)
                .map(|_| init::linear(rng, d, d, true, 1.0, device))
                .collect(),
            out: init::linear(rng, d, 1, true, OUTPUT_GAIN, device),
        }
    }

    /// Conditioned densities `u_hat` [K] (see [`Tokenizer::condition`]), `tau` [M] → Δu [K, M].
    pub fn forward(&self, u_hat: Tensor<1>, tau: Tensor<1>) -> Tensor<2> {
        let [k] = u_hat.dims();
        let [m] = tau.dims();
        let (mut x, _) = self.tokenizer.forward(u_hat, tau);
        for layer in &self.hidden {
            x = silu(init::apply_rows(layer, x));
        }
        init::apply_rows(&self.out, x).reshape([k, m])
    }
}
