//! Tokenisation x_{i,m} = γ_u(u_i^(c)) + γ_s(τ_m) (paper eq. `gscnet_token`).
//!
//! Each encoder γ is Fourier features → linear → SiLU. The raw density is first conditioned to
//! û = u / (s + |u|) ∈ (−1, 1) (s = `u_scale`), so raw densities far outside softplus's linear
//! range (|u| ~ 1e3, or ±∞ clamped to ±1e30) still give bounded, finite features; the spectral
//! coordinate is mapped to τ̂ = 2τ − 1 (τ ∈ [0, 1] → [−1, 1]). Features of a scalar v are
//! [v, sin(2^k π v), cos(2^k π v)] for k = 0..F.

use crate::init::SeedStream;
use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::{Device, Tensor, TensorData};

use crate::init;
use crate::ops::silu;

/// Fourier features of a column of scalars: `v` [n, 1] → [n, 1 + 2F].
pub fn fourier_features(v: Tensor<2>, frequencies: usize) -> Tensor<2> {
    if frequencies == 0 {
        return v;
    }
    let device = v.device();
    let omega: Vec<f32> = (0..frequencies)
        .map(|k| std::f32::consts::PI * (1u32 << k) as f32)
        .collect();
    let omega = Tensor::<2>::from_data(TensorData::new(omega, [1, frequencies]), &device);
    let phase = v.clone().mul(omega);
    Tensor::cat(vec![v, phase.clone().sin(), phase.cos()], 1)
}

/// Raw-density conditioning û = u / (s + |u|), with non-finite magnitudes clamped to ±1e30
/// first (NaN stays NaN).
pub fn condition_raw_density<const D: usize>(u: Tensor<D>, scale: f32) -> Tensor<D> {
    let u = u.clamp(-1e30, 1e30);
    u.clone().div(u.abs().add_scalar(scale))
}

/// The two token encoders γ_u and γ_s.
#[derive(Module, Debug)]
pub struct Tokenizer {
    density: Linear,
    spectral: Linear,
    frequencies: usize,
    u_scale: f32,
    /// Centre c of the conditioning (0 unless set from data): û = (u − c)/(s + |u − c|).
    u_centre: f32,
}

impl Tokenizer {
    pub(crate) fn new(
        rng: &mut SeedStream,
        width: usize,
        frequencies: usize,
        u_scale: f32,
        device: &Device,
    ) -> Self {
        let features = 1 + 2 * frequencies;
        Self {
            density: init::linear(rng, features, width, true, 1.0, device),
            spectral: init::linear(rng, features, width, true, 1.0, device),
            frequencies,
            u_scale,
            u_centre: 0.0,
        }
    }

    /// Condition around `centre` with scale `scale` (both in raw-density units; the caller
    /// checks they are finite and `scale` > 0).
    pub(crate) fn set_conditioning(&mut self, centre: f32, scale: f32) {
        self.u_centre = centre;
        self.u_scale = scale;
    }

    /// The conditioned raw density û = (u − c)/(s + |u − c|) ∈ [−1, 1] of `u_c` [K] (c = 0 and
    /// s = `u_scale` unless set from data): the only way a Gaussian enters the network.
    pub fn condition(&self, u_c: Tensor<1>) -> Tensor<1> {
        condition_raw_density(u_c.sub_scalar(self.u_centre), self.u_scale)
    }

    /// γ_u for conditioned densities `u_hat` [K] → [K, d].
    pub fn encode_density(&self, u_hat: Tensor<1>) -> Tensor<2> {
        let [k] = u_hat.dims();
        silu(
            self.density
                .forward(fourier_features(u_hat.reshape([k, 1]), self.frequencies)),
        )
    }

    /// γ_s(τ) for `tau` [M] → [M, d].
    pub fn encode_spectral(&self, tau: Tensor<1>) -> Tensor<2> {
        let [m] = tau.dims();
        let tau_hat = tau.mul_scalar(2.0).sub_scalar(1.0).reshape([m, 1]);
        silu(
            self.spectral
                .forward(fourier_features(tau_hat, self.frequencies)),
        )
    }

    /// Tokens x_{i,m} = γ_u(û_i) + γ_s(τ_m) for conditioned densities `u_hat` [K]: `[K, M, d]`,
    /// together with γ_s(τ) `[M, d]`.
    pub fn forward(&self, u_hat: Tensor<1>, tau: Tensor<1>) -> (Tensor<3>, Tensor<2>) {
        let gu = self.encode_density(u_hat);
        let gs = self.encode_spectral(tau);
        let tokens = gu
            .unsqueeze_dim::<3>(1)
            .add(gs.clone().unsqueeze_dim::<3>(0));
        (tokens, gs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fourier_features_match_closed_form() {
        let device = crate::test_util::cpu();
        let v = Tensor::<2>::from_data(TensorData::new(vec![0.25f32, -0.5], [2, 1]), &device);
        let f: Vec<f32> = fourier_features(v, 2).into_data().try_into_vec().unwrap();
        let pi = std::f32::consts::PI;
        let expect = [
            0.25,
            (pi * 0.25).sin(),
            (2.0 * pi * 0.25).sin(),
            (pi * 0.25).cos(),
            (2.0 * pi * 0.25).cos(),
            -0.5,
            (-pi * 0.5).sin(),
            (-2.0 * pi * 0.5).sin(),
            (-pi * 0.5).cos(),
            (-2.0 * pi * 0.5).cos(),
        ];
        for (a, b) in f.iter().zip(expect) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
    }

    #[test]
    fn conditioning_is_bounded_and_odd() {
        let device = crate::test_util::cpu();
        let u = Tensor::<1>::from_floats(
            [-1e3, -4.0, 0.0, 4.0, 1e3, f32::INFINITY, f32::NEG_INFINITY],
            &device,
        );
        let c: Vec<f32> = condition_raw_density(u, 4.0)
            .into_data()
            .try_into_vec()
            .unwrap();
        let expect = [-1e3 / 1004.0, -0.5, 0.0, 0.5, 1e3 / 1004.0, 1.0, -1.0];
        for (a, b) in c.iter().zip(expect) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
    }
}
