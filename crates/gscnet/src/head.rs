//! The density-curve head (paper eqs. `gscnet_basis_response`, `gscnet_curve_head`):
//!
//! ```text
//! Δu_{i,m} = δ^tok_{i,m} + δ^basis_{i,m} + δ^res_{i,m}
//! δ^tok_{i,m}   = h_{i,m} · w_tok + b_tok                      (from each token)
//! δ^basis_{i,m} = Σ_r a_{i,r} B_{r,m},   a_i = p_i W_a          (learnable basis B ∈ R^{R×M})
//! δ^res_{i,m}   = w_res · SiLU(p_i W_p + γ_s(τ_m) W_s + b) + b_res
//! ```
//!
//! p_i = mean_m h_{i,m} is the pooled feature. The paper leaves the form of the residual response
//! open beyond "from p_i"; here it is a one-hidden-layer decoder of p_i conditioned on the
//! spectral embedding, so it is not a second linear map of p_i (which the basis term already is).
//! The basis B has one column per observed grid point, which ties a model to its M channels.
//! Output layers and B start at 1e-2 of the usual scale, so Δu ≈ 0 at initialisation (stage 2
//! starts from the stage-1 densities) while every parameter still receives a gradient.

use crate::init::SeedStream;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::{Device, Tensor};

use crate::init;
use crate::ops::silu;

/// Scale of the head's output layers relative to the default initialisation.
pub(crate) const OUTPUT_GAIN: f32 = 1e-2;

/// Token, low-rank basis and residual responses.
#[derive(Module, Debug)]
pub struct CurveHead {
    pub token: Linear,
    pub coefficients: Linear,
    pub basis: Param<Tensor<2>>,
    pub residual_pooled: Linear,
    pub residual_spectral: Linear,
    pub residual_out: Linear,
}

impl CurveHead {
    pub(crate) fn new(
        rng: &mut SeedStream,
        width: usize,
        rank: usize,
        channels: usize,
        device: &Device,
    ) -> Self {
        Self {
            token: init::linear(rng, width, 1, true, OUTPUT_GAIN, device),
            coefficients: init::linear(rng, width, rank, false, 1.0, device),
            basis: init::uniform(rng, [rank, channels], OUTPUT_GAIN, device),
            residual_pooled: init::linear(rng, width, width, true, 1.0, device),
            residual_spectral: init::linear(rng, width, width, false, 1.0, device),
            residual_out: init::linear(rng, width, 1, true, OUTPUT_GAIN, device),
        }
    }

    /// `h` [K, M, d] (token features), `spectral` [M, d] (γ_s(τ)) → Δu [K, M].
    pub fn forward(&self, h: Tensor<3>, spectral: Tensor<2>) -> Tensor<2> {
        let [k, m, _] = h.dims();
        let pooled = h.clone().mean_dim(1).squeeze_dim::<2>(1); // [K, d]
        let tok = init::apply_rows(&self.token, h).reshape([k, m]);
        let basis = self
            .coefficients
            .forward(pooled.clone())
            .matmul(self.basis.val());
        let hidden = self
            .residual_pooled
            .forward(pooled)
            .unsqueeze_dim::<3>(1)
            .add(
                self.residual_spectral
                    .forward(spectral)
                    .unsqueeze_dim::<3>(0),
            );
        let res = init::apply_rows(&self.residual_out, silu(hidden)).reshape([k, m]);
        tok.add(basis).add(res)
    }
}
