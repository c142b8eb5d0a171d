//! What a stage may train or apply between the model's density columns and the channels it
//! supervises. The loop knows these two shapes only; the method that needs one defines it
//! (4D-SG: its curve model is a [`DensityNet`], its basis-material head a [`ChannelMix`]).

use crate::Result;
use crate::gaussians::GaussianModel;
use crate::gaussians::adam::LogLinear;
use crate::record::resume::NetState;
use burn::tensor::{Gradients, Tensor};
use std::path::Path;

/// A network trained with the model: it turns the model's common raw density u⁽ᶜ⁾ (density
/// column 0) into every supervised channel's raw density u⁽ᶜ⁾ + Δu `[K, M]` (rendered as
/// softplus), and has its own optimiser and learning-rate schedule. Further density columns, if
/// it reads any ([`DensityNet::columns`]), are per-Gaussian parameters of its own, trained at the
/// density's rate (4D-SG's channel residuals).
pub trait DensityNet: 'static {
    /// The channels M it predicts.
    fn channels(&self) -> usize;

    /// The model's density columns it reads: 1 (u⁽ᶜ⁾), or more with per-Gaussian parameters.
    fn columns(&self) -> usize {
        1
    }

    /// Δu `[K, M]` from the density columns u `[K, columns]`, on the autodiff device (gradients
    /// flow to u and the net).
    fn offsets(&self, u: Tensor<2>) -> Result<Tensor<2>>;

    /// Its regulariser on the density columns `u` and their `offsets`, and that term's weight,
    /// or None when it has none (weight 0).
    fn regulariser(&self, u: Tensor<2>, offsets: Tensor<2>) -> Result<Option<(Tensor<1>, f64)>>;

    /// The learning-rate schedule of the network.
    fn lr(&self) -> LogLinear;

    /// One optimiser step of the network at rate `lr` from the step's gradients.
    fn step(&mut self, grads: Gradients, lr: f64);

    /// The network and its optimiser as exact records (for checkpoints).
    fn state(&self) -> Result<NetState>;

    /// Load `state` (saved by [`DensityNet::state`]); errors name `<prefix>net` of `file`.
    fn restore(&mut self, state: &NetState, file: &Path, prefix: &str) -> Result<()>;

    /// Raw per-channel densities u + Δu `[K, M]` of `model` (no gradient), for scoring, saving
    /// and queries.
    fn raw_densities(&self, model: &GaussianModel) -> Result<Tensor<2>> {
        let u = model.densities.value.clone();
        let du = self.offsets(u.clone().autodiff())?.inner();
        Ok(common_density(u) + du)
    }
}

/// The common raw density u⁽ᶜ⁾ `[K, 1]`: column 0 of a density network's columns `u`.
pub fn common_density(u: Tensor<2>) -> Tensor<2> {
    match u.dims()[1] {
        1 => u,
        _ => u.narrow(1, 0, 1),
    }
}

/// A fixed map from the rendered density columns to the supervised channels' line integrals
/// (no parameters of its own: the model's columns are what it mixes).
pub trait ChannelMix {
    /// `(channels formed, density columns of the model it reads)`.
    fn shape(&self) -> (usize, usize);

    /// The channels' line integrals `[V, M, rows, cols]` from the rendered columns
    /// `[V, columns, rows, cols]`.
    fn project(&self, rendered: Tensor<4>) -> Tensor<4>;

    /// Raw per-channel densities `[K, M]` of `model`, for scoring (what a channel's voxelized
    /// volume is made of).
    fn channel_raw(&self, model: &GaussianModel) -> Tensor<2>;
}
