//! What a stage may train or apply between the model's density columns and the channels it
//! supervises. The loop knows these two shapes only; the method that needs one defines it
//! (4D-SG: its curve model is a [`DensityNet`], its basis-material head a [`ChannelMix`]).

use crate::Result;
use crate::gaussians::GaussianModel;
use crate::gaussians::adam::LogLinear;
use crate::record::resume::NetState;
use burn::tensor::{Gradients, Tensor};
use std::path::Path;

/// A network trained with the model: it turns the model's one raw density column u `[K, 1]`
/// into every supervised channel's raw density u + Δu `[K, M]` (rendered as softplus), and has
/// its own optimiser and learning-rate schedule.
pub trait DensityNet: 'static {
    /// The channels M it predicts.
    fn channels(&self) -> usize;

    /// Δu `[K, M]` from u `[K, 1]`, on the autodiff device (gradients flow to u and the net).
    fn offsets(&self, u: Tensor<2>) -> Result<Tensor<2>>;

    /// Its regulariser on `offsets` and that term's weight, or None when it has none (weight 0).
    fn regulariser(&self, offsets: Tensor<2>) -> Result<Option<(Tensor<1>, f64)>>;

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
        Ok(u + du)
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
