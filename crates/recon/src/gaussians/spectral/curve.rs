//! The curve model as a trainable part of a stage (4D-SG stage 2): GSC-Net or the MLP with its
//! own optimiser, evaluated on the observed spectral grid.

use crate::Result;
use crate::gaussians::GaussianModel;
use crate::gaussians::adam::LogLinear;
use burn::optim::ModuleOptimizer;
use burn::tensor::Tensor;
use prism_gscnet::CurveModel;

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

impl CurveFit {
    /// Raw per-channel densities u⁽ᶜ⁾ + Δu `[K, M]` of `model` (no gradient), for saving and
    /// for queries.
    pub fn raw_densities(&self, model: &GaussianModel) -> Result<Tensor<2>> {
        let u = model.densities.value.clone();
        let k = u.dims()[0];
        let du = self
            .net
            .forward(u.clone().autodiff().reshape([k]), self.tau.clone())?
            .inner();
        Ok(u + du)
    }
}
