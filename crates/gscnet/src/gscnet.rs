//! GSC-Net (paper Sec. III-D): tokeniser → stacked gated spectral SSM blocks → curve head.

use crate::init::SeedStream;
use burn::module::Module;
use burn::tensor::{Device, Tensor};

use crate::block::{BlockShape, SpectralBlock};
use crate::config::CurveModelConfig;
use crate::head::CurveHead;
use crate::tokenizer::Tokenizer;

/// The Gaussian-wise spectral density curve network, batched over K Gaussians × M channels.
#[derive(Module, Debug)]
pub struct GscNet {
    pub tokenizer: Tokenizer,
    pub blocks: Vec<SpectralBlock>,
    pub head: CurveHead,
}

impl GscNet {
    /// Build for `channels` = M grid points (config already validated, M ≥ 2).
    pub(crate) fn new(
        rng: &mut SeedStream,
        config: &CurveModelConfig,
        channels: usize,
        device: &Device,
    ) -> Self {
        let shape = BlockShape {
            width: config.width,
            state: config.state_size,
            kernel: config.conv_kernel,
            dt_min: config.dt_min,
            dt_max: config.dt_max,
        };
        Self {
            tokenizer: Tokenizer::new(
                rng,
                config.width,
                config.fourier_frequencies,
                config.u_scale,
                device,
            ),
            blocks: (0..config.depth)
                .map(|_| SpectralBlock::new(rng, shape, device))
                .collect(),
            head: CurveHead::new(rng, config.width, config.rank, channels, device),
        }
    }

    /// Conditioned densities `u_hat` [K] (see [`Tokenizer::condition`]), `tau` [M] → Δu [K, M]
    /// (shapes checked by [`crate::CurveModel::forward`]).
    pub fn forward(&self, u_hat: Tensor<1>, tau: Tensor<1>) -> Tensor<2> {
        let (mut x, spectral) = self.tokenizer.forward(u_hat, tau);
        for block in &self.blocks {
            x = block.forward(x);
        }
        self.head.forward(x, spectral)
    }
}
