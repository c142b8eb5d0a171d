//! The curve model as a trainable part of a stage (4D-SG stage 2): GSC-Net or the MLP with its
//! own optimiser, evaluated on the observed spectral grid, and optionally a free residual per
//! Gaussian and channel on top of it; the loop trains it as a [`DensityNet`].

use crate::Result;
use crate::gaussians::adam::LogLinear;
use crate::gaussians::train::{DensityNet, common_density};
use crate::record::resume::NetState;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Gradients, Tensor};
use prism_gscnet::{CurveModel, curve_regularizer};
use std::path::Path;

/// The curve model in training: the model's density column 0 is the common raw density u⁽ᶜ⁾
/// `[K, 1]` and the network predicts Δu `[K, M]` on the observed spectral grid; the rendered
/// densities are softplus(u⁽ᶜ⁾ + Δu). The network has its own Adam (Burn's module optimiser).
/// With `residual`, density columns 1..=M are the channel residuals r, and Δu is the network's
/// curve plus r (`stage2.residual`).
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
    /// Weight of the channel residuals' mean square, when the model carries them.
    pub residual: Option<f64>,
}

impl CurveFit {
    /// The channel residuals r `[K, M]` of the density columns `u` and their weight (None
    /// without them).
    fn residuals(&self, u: &Tensor<2>) -> Result<Option<(Tensor<2>, f64)>> {
        let Some(weight) = self.residual else {
            return Ok(None);
        };
        let m = self.channels();
        let [_, d] = u.dims();
        if d != 1 + m {
            return Err(crate::Error::invalid(
                "stage2.residual",
                format!("{d} density columns, expected the common density and {m} residuals"),
            ));
        }
        Ok(Some((u.clone().narrow(1, 1, m), weight)))
    }
}

impl DensityNet for CurveFit {
    fn channels(&self) -> usize {
        self.net.channels()
    }

    fn columns(&self) -> usize {
        match self.residual {
            Some(_) => 1 + self.channels(),
            None => 1,
        }
    }

    fn offsets(&self, u: Tensor<2>) -> Result<Tensor<2>> {
        let k = u.dims()[0];
        let r = self.residuals(&u)?;
        let du = self
            .net
            .forward(common_density(u).reshape([k]), self.tau.clone())?;
        Ok(match r {
            Some((r, _)) => du + r,
            None => du,
        })
    }

    /// L_curve, the first-order smoothness of the network's Δu along the spectral axis, weighted
    /// by `lambda_curve`; with residuals, `lambda_curve · L_curve + weight · mean(r²)` (weight 1).
    fn regulariser(&self, u: Tensor<2>, offsets: Tensor<2>) -> Result<Option<(Tensor<1>, f64)>> {
        let curve = |du: Tensor<2>| -> Result<Option<Tensor<1>>> {
            Ok(match self.lambda_curve > 0.0 {
                true => Some(curve_regularizer(du)?),
                false => None,
            })
        };
        let Some((r, weight)) = self.residuals(&u)? else {
            return Ok(curve(offsets)?.map(|l| (l, self.lambda_curve)));
        };
        let penalty = r.clone().powi_scalar(2).mean() * weight;
        Ok(Some(match curve(offsets - r)? {
            Some(l) => (l * self.lambda_curve + penalty, 1.0),
            None => (penalty, 1.0),
        }))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::{cpu_device, host_values};
    use burn::optim::AdamConfig;
    use burn::tensor::TensorData;
    use prism_gscnet::{CurveModelConfig, SpectralGrid};

    fn fit(residual: Option<f64>) -> CurveFit {
        let ad = cpu_device().autodiff();
        let grid = SpectralGrid::new(vec![0.0, 0.4, 1.0]).unwrap();
        let cfg = CurveModelConfig {
            width: 8,
            depth: 1,
            ..CurveModelConfig::default()
        };
        CurveFit {
            net: cfg.init(&grid, &ad, 3).unwrap(),
            optim: AdamConfig::new().init(),
            tau: grid.to_tensor(&ad),
            lambda_curve: 0.01,
            lr: LogLinear {
                init: 1e-3,
                end: 1e-4,
            },
            residual,
        }
    }

    /// Density columns `[K = 2, 1 + 3]`: u⁽ᶜ⁾ and three residuals per Gaussian.
    fn columns() -> Tensor<2> {
        let v = vec![-1.0f32, 0.1, -0.2, 0.3, 0.5, 0.0, 0.4, -0.6];
        Tensor::from_data(TensorData::new(v, [2, 4]), &cpu_device().autodiff())
    }

    /// With residuals, Δu is the network's curve of u⁽ᶜ⁾ plus each Gaussian's residual, and the
    /// regulariser is `λ_curve·L_curve(curve) + weight·mean(r²)`; the residuals get the data
    /// term's gradient of their channel's raw density plus the penalty's `2·weight·r/(K·M)`.
    #[test]
    fn residuals_add_to_the_curve_and_are_penalised_in_mean_square() {
        let (plain, with) = (fit(None), fit(Some(0.5)));
        assert_eq!((plain.columns(), with.columns()), (1, 4));
        let u = columns();
        let curve = host_values(&plain.offsets(u.clone().narrow(1, 0, 1)).unwrap());
        let du = with.offsets(u.clone()).unwrap();
        let r = host_values(&u.clone().narrow(1, 1, 3));
        for (i, v) in host_values(&du).iter().enumerate() {
            assert!((v - (curve[i] + r[i])).abs() <= 1e-6, "{i}: {v}");
        }
        let lc =
            host_values(&curve_regularizer(du.clone() - u.clone().narrow(1, 1, 3)).unwrap())[0];
        let (l, w) = with.regulariser(u.clone(), du.clone()).unwrap().unwrap();
        let mean_sq = r.iter().map(|x| x * x).sum::<f32>() / 6.0;
        let want = 0.01 * lc + 0.5 * mean_sq;
        assert_eq!(w, 1.0);
        assert!((host_values(&l)[0] - want).abs() <= 1e-6 * want.abs().max(1e-3));

        // d/dr of Σ du (a stand-in data term, gradient 1 per entry) + the penalty.
        let leaf = u.require_grad();
        let du = with.offsets(leaf.clone()).unwrap();
        let (l, _) = with.regulariser(leaf.clone(), du.clone()).unwrap().unwrap();
        let grads = (du.sum() + l).backward();
        let g = host_values(&leaf.grad(&grads).unwrap().narrow(1, 1, 3));
        for (i, (g, r)) in g.iter().zip(&r).enumerate() {
            let want = 1.0 + 2.0 * 0.5 * r / 6.0;
            assert!((g - want).abs() <= 1e-5, "{i}: {g} vs {want}");
        }
        // Without residual columns the fit refuses, naming the setting.
        let e = with
            .offsets(columns().narrow(1, 0, 2))
            .unwrap_err()
            .to_string();
        assert!(e.contains("stage2.residual"), "{e}");
    }
}
