//! The trainable Gaussian model: raw parameter tensors with their Adam state, activations, and
//! the bridge to and from [`HostGaussians`].
//!
//! Activations (R²-Gaussian): density = softplus(raw), scale = min + (max − min)·sigmoid(raw),
//! rotation = the raw quaternion (normalised inside the render op). Positions are unconstrained.

use super::adam::AdamParam;
use super::host::{HostGaussians, ScaleBounds};
use crate::device::{host_values, upload};
use burn::tensor::{Device, Tensor};
use prism_gscnet::ops::{Activation, activate};
use prism_render::Gaussians;

/// Which parameter groups receive gradients and Adam steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Learnable {
    pub position: bool,
    pub rotation: bool,
    pub scale: bool,
    pub density: bool,
}

impl Learnable {
    pub const ALL: Learnable = Learnable {
        position: true,
        rotation: true,
        scale: true,
        density: true,
    };
    pub const DENSITY: Learnable = Learnable {
        position: false,
        rotation: false,
        scale: false,
        density: true,
    };
}

/// Overflow-free softplus on tensors ([`Activation::Softplus`]).
pub fn softplus(x: Tensor<2>) -> Tensor<2> {
    activate(x, Activation::Softplus)
}

/// Raw parameters on a device with their optimiser state.
#[derive(Clone, Debug)]
pub struct GaussianModel {
    pub means: AdamParam,
    pub scales: AdamParam,
    pub rotations: AdamParam,
    pub densities: AdamParam,
    pub bounds: ScaleBounds,
}

/// The activated Gaussians of one forward pass and the leaf tensors that carry gradients.
pub struct Activated {
    pub gaussians: Gaussians,
    /// Raw leaves `[means, scales, rotations, densities]` (tracked where learnable).
    pub leaves: [Tensor<2>; 4],
}

impl GaussianModel {
    /// Upload host parameters (fresh optimiser state).
    pub fn new(host: &HostGaussians, bounds: ScaleBounds, device: &Device) -> Self {
        GaussianModel {
            means: AdamParam::new(upload(host.means.clone(), 3, device)),
            scales: AdamParam::new(upload(host.scales.clone(), 3, device)),
            rotations: AdamParam::new(upload(host.rotations.clone(), 4, device)),
            densities: AdamParam::new(upload(host.densities.clone(), host.channels, device)),
            bounds,
        }
    }

    pub fn len(&self) -> usize {
        self.means.value.dims()[0]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn channels(&self) -> usize {
        self.densities.value.dims()[1]
    }

    pub fn device(&self) -> Device {
        self.means.value.device()
    }

    /// Copy the raw parameters to the host.
    pub fn to_host(&self) -> HostGaussians {
        HostGaussians {
            channels: self.channels(),
            means: host_values(&self.means.value),
            scales: host_values(&self.scales.value),
            rotations: host_values(&self.rotations.value),
            densities: host_values(&self.densities.value),
        }
    }

    /// Replace the parameters by `host`, whose row `i` came from old row `src[i]` (`None`: a new
    /// Gaussian with zero Adam moments).
    pub fn remap(&mut self, host: &HostGaussians, src: &[Option<usize>]) {
        let device = self.device();
        self.means
            .remap(upload(host.means.clone(), 3, &device), src);
        self.scales
            .remap(upload(host.scales.clone(), 3, &device), src);
        self.rotations
            .remap(upload(host.rotations.clone(), 4, &device), src);
        self.densities
            .remap(upload(host.densities.clone(), host.channels, &device), src);
    }

    /// Replace the density columns (e.g. one column per channel after the structural stage);
    /// their optimiser state starts from zero.
    pub fn set_densities(&mut self, raw: Tensor<2>) {
        self.densities = AdamParam::new(raw);
    }

    /// Append `n` density columns of zeros with zero Adam moments; the existing columns keep
    /// their values and moments, and the group its step count.
    pub fn append_density_columns(&mut self, n: usize) {
        let (m1, m2, steps) = self.densities.state();
        let zeros = Tensor::zeros([self.len(), n], &self.device());
        let cat = |t: &Tensor<2>| Tensor::cat(vec![t.clone(), zeros.clone()], 1);
        self.densities = AdamParam::with_state(cat(&self.densities.value), cat(m1), cat(m2), steps);
    }

    /// Activated Gaussians. With `learn`, the listed groups become autodiff leaves that require
    /// gradients (on the autodiff form of the model's device); without, plain tensors.
    pub fn activate(&self, learn: Option<Learnable>) -> Activated {
        let leaf = |p: &AdamParam, on: bool| -> Tensor<2> {
            match learn {
                Some(_) if on => p.value.clone().autodiff().require_grad(),
                Some(_) => p.value.clone().autodiff(),
                None => p.value.clone(),
            }
        };
        let l = learn.unwrap_or(Learnable::ALL);
        let leaves = [
            leaf(&self.means, l.position),
            leaf(&self.scales, l.scale),
            leaf(&self.rotations, l.rotation),
            leaf(&self.densities, l.density),
        ];
        let (lo, hi) = (self.bounds.min, self.bounds.max);
        let gaussians = Gaussians {
            means: leaves[0].clone(),
            scales: activate(
                leaves[1].clone(),
                // As `σ · (hi − lo) + lo` with f64 scalars: the span rounded once to f32.
                Activation::Sigmoid {
                    lo: lo as f32,
                    span: (hi - lo) as f32,
                },
            ),
            rotations: leaves[2].clone(),
            densities: softplus(leaves[3].clone()),
        };
        Activated { gaussians, leaves }
    }
}
