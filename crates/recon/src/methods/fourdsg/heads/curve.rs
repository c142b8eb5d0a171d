//! The curve model as a trainable part of a stage (4D-SG stage 2): GSC-Net or the MLP with its
//! own optimiser, evaluated on the observed spectral grid; the loop trains it as a
//! [`DensityNet`].

use crate::Result;
use crate::gaussians::adam::LogLinear;
use crate::gaussians::train::DensityNet;
use crate::record::resume::NetState;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Gradients, Tensor};
use prism_gscnet::{CurveModel, curve_regularizer};
use std::path::Path;

/// The curve model in training: the model's density column is the common raw density u⁽ᶜ⁾
/// `[K, 1]` and the network predicts Δu `[K, M]` on the observed spectral grid; the rendered
/// densities are softplus(u⁽ᶜ⁾ + Δu). The network has its own Adam (Burn's module optimiser).
pub struct CurveFit {
    /// The curve model, on the autodiff form of the training device.
    pub net: CurveModel,
    pub optim: ModuleOptimizer,
    /// The observed grid τ [M] (autodiff device).
    pub tau: Tensor<1>,
    /// Weight of the curve smoothness term L_curve.
    pub lambda_curve: f64,
    /// Learning rate of the network.
    pub lr: LogLinear,
}

impl DensityNet for CurveFit {
    fn channels(&self) -> usize {
        self.net.channels()
    }

    fn offsets(&self, u: Tensor<2>) -> Result<Tensor<2>> {
        let k = u.dims()[0];
        Ok(self.net.forward(u.reshape([k]), self.tau.clone())?)
    }

    /// L_curve, the first-order smoothness of Δu along the spectral axis, weighted by
    /// `lambda_curve`.
    fn regulariser(&self, offsets: Tensor<2>) -> Result<Option<(Tensor<1>, f64)>> {
        if self.lambda_curve > 0.0 {
            Ok(Some((curve_regularizer(offsets)?, self.lambda_curve)))
        } else {
            Ok(None)
        }
    }

    fn lr(&self) -> LogLinear {
        self.lr
    }

    fn step(&mut self, grads: Gradients, lr: f64) {
        let gp = GradientsParams::from_grads(grads, &self.net);
        self.net = self.optim.step(lr, self.net.clone(), gp);
    }

    fn state(&self) -> Result<NetState> {
        NetState::of(&self.net, &self.optim)
    }

    fn restore(&mut self, state: &NetState, file: &Path, prefix: &str) -> Result<()> {
        state.restore(&mut self.net, &mut self.optim, file, prefix)
    }
}
