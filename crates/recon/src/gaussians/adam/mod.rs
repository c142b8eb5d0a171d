//! Adam over raw parameter tensors whose row count changes (densification and pruning), with a
//! log-linear learning-rate decay per parameter group.
//!
//! Burn's module optimiser cannot resize its state, so each parameter tensor carries its own
//! moments here. Rows created by densification start with zero moments; pruned rows drop theirs.
//! The step counter (bias correction) is per tensor, as in 3DGS.
//!
//! On the CPU backends a step is one fused op ([`cpu`]: one multi-threaded pass, bit-identical to
//! the composed form); on wgpu Burn's element-wise ops run it ([`AdamParam::composed_step`]).

// The NdArray selector names burn-ndarray, deprecated in Burn 0.22 (Flex is its successor).
#![allow(deprecated)]

pub mod cpu;

use burn::backend::autodiff::{Autodiff, checkpoint::strategy::CheckpointStrategy};
use burn::backend::{Backend, Dispatch, backend_extension, tensor::FloatTensor};
use burn::tensor::Tensor;
use cpu::AdamScalars;
use prism_kernel::autodiff::{inner, lift};

/// `lr(t) = exp((1 − f)·ln lr₀ + f·ln lr₁)`, `f = min(t / steps, 1)`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LogLinear {
    pub init: f64,
    #[serde(rename = "final")]
    pub end: f64,
}

impl LogLinear {
    pub fn at(&self, t: usize, steps: usize) -> f64 {
        let f = if steps == 0 {
            1.0
        } else {
            (t as f64 / steps as f64).min(1.0)
        };
        ((1.0 - f) * self.init.ln() + f * self.end.ln()).exp()
    }

    pub fn validate(&self, field: &str) -> crate::Result<()> {
        for (name, v) in [("init", self.init), ("final", self.end)] {
            prism_domain::error::ensure_positive(format!("{field}.{name}"), v)?;
        }
        Ok(())
    }
}

pub const BETA1: f64 = 0.9;
pub const BETA2: f64 = 0.999;
/// R²-Gaussian's ε (PyTorch's default is 1e-8; densities and positions have tiny gradients).
pub const EPS: f64 = 1e-15;

/// One parameter tensor `[K, D]` and its Adam moments.
#[derive(Clone, Debug)]
pub struct AdamParam {
    pub value: Tensor<2>,
    m1: Tensor<2>,
    m2: Tensor<2>,
    steps: i32,
}

impl AdamParam {
    pub fn new(value: Tensor<2>) -> Self {
        AdamParam {
            m1: value.zeros_like(),
            m2: value.zeros_like(),
            value,
            steps: 0,
        }
    }

    /// A parameter with saved optimiser state: moments of the value's shape and the number of
    /// steps taken (the bias corrections' exponent).
    pub fn with_state(value: Tensor<2>, m1: Tensor<2>, m2: Tensor<2>, steps: i32) -> Self {
        debug_assert_eq!(value.dims(), m1.dims());
        debug_assert_eq!(value.dims(), m2.dims());
        AdamParam {
            value,
            m1,
            m2,
            steps,
        }
    }

    /// The optimiser state: (first moment, second moment, steps taken).
    pub fn state(&self) -> (&Tensor<2>, &Tensor<2>, i32) {
        (&self.m1, &self.m2, self.steps)
    }

    /// One Adam step with learning rate `lr` and gradient `grad` (same shape as the value): the
    /// fused op on the CPU backends, [`AdamParam::composed_step`] on wgpu.
    pub fn step(&mut self, grad: Tensor<2>, lr: f64) {
        if prism_render::ops::is_gpu(&grad.device()) {
            return self.composed_step(grad, lr);
        }
        assert_eq!(grad.dims(), self.value.dims(), "adam: gradient shape");
        self.steps += 1;
        let (v, m1, m2) = Dispatch::adam_step(
            self.value.clone().into_dispatch(),
            self.m1.clone().into_dispatch(),
            self.m2.clone().into_dispatch(),
            grad.into_dispatch(),
            scalars(self.steps, lr),
        );
        self.value = Tensor::from_dispatch(v);
        self.m1 = Tensor::from_dispatch(m1);
        self.m2 = Tensor::from_dispatch(m2);
    }

    /// [`AdamParam::step`] composed of Burn's element-wise ops.
    pub fn composed_step(&mut self, grad: Tensor<2>, lr: f64) {
        self.steps += 1;
        let m1 = self.m1.clone() * BETA1 + grad.clone() * (1.0 - BETA1);
        let m2 = self.m2.clone() * BETA2 + grad.clone() * grad * (1.0 - BETA2);
        let c1 = 1.0 - BETA1.powi(self.steps);
        let c2 = 1.0 - BETA2.powi(self.steps);
        let update = (m1.clone() / c1) / ((m2.clone() / c2).sqrt() + EPS);
        self.value = self.value.clone() - update * lr;
        self.m1 = m1;
        self.m2 = m2;
    }

    /// Replace the value by `value` whose row `i` came from old row `src[i]` (its moments move
    /// with it) or is new (`None`: zero moments).
    pub fn remap(&mut self, value: Tensor<2>, src: &[Option<usize>]) {
        let [k, d] = value.dims();
        debug_assert_eq!(k, src.len());
        let device = value.device();
        let gather = |t: &Tensor<2>| -> Tensor<2> {
            let old = crate::device::host_values(t);
            let mut out = vec![0.0f32; k * d];
            for (i, s) in src.iter().enumerate() {
                if let Some(j) = *s {
                    out[i * d..(i + 1) * d].copy_from_slice(&old[j * d..(j + 1) * d]);
                }
            }
            crate::device::upload(out, d, &device)
        };
        self.m1 = gather(&self.m1);
        self.m2 = gather(&self.m2);
        self.value = value;
    }

    /// Shapes of (value, first moment, second moment), for checks.
    pub fn shapes(&self) -> [[usize; 2]; 3] {
        [self.value.dims(), self.m1.dims(), self.m2.dims()]
    }
}

/// The scalars of step `t` (1-based) with learning rate `lr`, as the composed form rounds them.
fn scalars(t: i32, lr: f64) -> AdamScalars {
    AdamScalars {
        beta1: BETA1 as f32,
        one_minus_beta1: (1.0 - BETA1) as f32,
        beta2: BETA2 as f32,
        one_minus_beta2: (1.0 - BETA2) as f32,
        correction1: (1.0 - BETA1.powi(t)) as f32,
        correction2: (1.0 - BETA2.powi(t)) as f32,
        eps: EPS as f32,
        lr: lr as f32,
    }
}

/// The fused Adam step ([`cpu::adam_step`]). Parameters are not on an autodiff graph: over
/// Autodiff the inner op runs untracked.
#[backend_extension(NdArray: cfg(feature = "ndarray"), Flex: cfg(feature = "flex"), Autodiff)]
pub trait AdamOps: Backend {
    /// The new `(value, first moment, second moment)` after one step with gradient `grad` (all
    /// four the same shape).
    fn adam_step(
        value: FloatTensor<Self>,
        m1: FloatTensor<Self>,
        m2: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        scalars: AdamScalars,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

#[cfg(any(feature = "flex", feature = "ndarray"))]
mod backends {
    macro_rules! impl_cpu_adam_ops {
        ($backend:ty) => {
            impl crate::gaussians::adam::AdamOps for $backend {
                fn adam_step(
                    value: FloatTensor<Self>,
                    m1: FloatTensor<Self>,
                    m2: FloatTensor<Self>,
                    grad: FloatTensor<Self>,
                    scalars: crate::gaussians::adam::cpu::AdamScalars,
                ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
                    let shape = Self::dims(&value);
                    let [v, a, b] = Self::with_values([&value, &m1, &m2, &grad], |[v, a, b, g]| {
                        crate::gaussians::adam::cpu::adam_step(&scalars, v, a, b, g)
                    });
                    (
                        Self::tensor(v, shape.clone()),
                        Self::tensor(a, shape.clone()),
                        Self::tensor(b, shape),
                    )
                }
            }
        };
    }

    #[cfg(feature = "flex")]
    mod flex {
        use burn::backend::{Flex, tensor::FloatTensor};
        use prism_kernel::cpu::CpuFloat;
        impl_cpu_adam_ops!(Flex);
    }

    // burn-ndarray is deprecated in Burn 0.22 (Flex is its successor); kept while it exists.
    #[cfg(feature = "ndarray")]
    mod ndarray {
        use burn::backend::{NdArray, tensor::FloatTensor};
        use prism_kernel::cpu::CpuFloat;
        impl_cpu_adam_ops!(NdArray);
    }
}

impl<B: AdamOps, C: CheckpointStrategy> AdamOps for Autodiff<B, C> {
    fn adam_step(
        value: FloatTensor<Self>,
        m1: FloatTensor<Self>,
        m2: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        scalars: AdamScalars,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let [value, m1, m2, grad] = inner([value, m1, m2, grad]);
        let (v, a, b) = B::adam_step(value, m1, m2, grad, scalars);
        let [v, a, b] = lift([v, a, b]);
        (v, a, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::host_values as values;
    use burn::tensor::TensorData;

    #[test]
    fn first_steps_match_the_closed_form_and_remap_moves_moments() {
        let dev = crate::device::cpu_device();
        let v = Tensor::<2>::from_data(TensorData::new(vec![1.0f32, -2.0], [2, 1]), &dev);
        let mut p = AdamParam::new(v);
        let g = Tensor::<2>::from_data(TensorData::new(vec![0.5f32, -3.0], [2, 1]), &dev);
        // Step 1: m̂ = g, v̂ = g², update = sign(g)·lr (ε negligible).
        p.step(g.clone(), 0.1);
        let a = values(&p.value);
        assert!(
            (a[0] - 0.9).abs() < 1e-6 && (a[1] + 1.9).abs() < 1e-6,
            "{a:?}"
        );
        // Step 2 with the same gradient: still exactly lr per step.
        p.step(g, 0.1);
        let a = values(&p.value);
        assert!(
            (a[0] - 0.8).abs() < 1e-6 && (a[1] + 1.8).abs() < 1e-6,
            "{a:?}"
        );
        // Keep row 1, add a new row: the new row's first step is a full lr step from zero
        // moments only if its gradient is the only contribution; the kept row keeps momentum.
        let nv = Tensor::<2>::from_data(TensorData::new(vec![-1.8f32, 5.0], [2, 1]), &dev);
        p.remap(nv, &[Some(1), None]);
        assert_eq!(p.shapes(), [[2, 1]; 3]);
        let m1 = values(&p.m1);
        assert!((m1[0] - (-3.0 * 0.1 - 3.0 * 0.09)).abs() < 1e-5, "{m1:?}");
        assert_eq!(m1[1], 0.0);
    }

    /// The fused step (CPU backends) and the composed form (wgpu) agree bit for bit over steps
    /// with changing gradients and rates, on more elements than one task holds; the autodiff
    /// device runs the same op untracked.
    #[test]
    fn fused_step_is_bit_identical_to_the_composed_form() {
        for dev in [
            crate::device::cpu_device(),
            crate::device::cpu_device().autodiff(),
        ] {
            let (k, d): (usize, usize) = (3001, 3);
            let noise = |seed: u32| -> Vec<f32> {
                (0..k * d)
                    .map(|i| {
                        let h = (i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8;
                        let u = h as f32 / 16777216.0 - 0.5;
                        // Magnitudes from 1e-9 to 1e3, some exact zeros.
                        if i % 97 == 0 {
                            0.0
                        } else {
                            u * 10f32.powi((i % 13) as i32 - 9)
                        }
                    })
                    .collect()
            };
            let t = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [k, d]), &dev);
            let mut fused = AdamParam::new(t(noise(1)));
            let mut composed = fused.clone();
            for step in 0..3u32 {
                let g = t(noise(10 + step));
                let lr = 1e-3 * (step + 1) as f64;
                fused.step(g.clone(), lr);
                composed.composed_step(g, lr);
                for (a, b) in [
                    (&fused.value, &composed.value),
                    (&fused.m1, &composed.m1),
                    (&fused.m2, &composed.m2),
                ] {
                    let (a, b) = (values(a), values(b));
                    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
                }
            }
            assert_eq!(fused.steps, composed.steps);
        }
    }

    #[test]
    fn log_linear_decay_hits_both_ends() {
        let s = LogLinear {
            init: 1e-2,
            end: 1e-3,
        };
        assert!((s.at(0, 100) - 1e-2).abs() < 1e-12);
        assert!((s.at(50, 100) - 10f64.powf(-2.5)).abs() < 1e-12);
        assert!((s.at(100, 100) - 1e-3).abs() < 1e-12);
        assert!((s.at(500, 100) - 1e-3).abs() < 1e-12);
    }
}
