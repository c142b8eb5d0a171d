//! The activations of the Gaussians' raw parameters (density = softplus(raw), scale = lo +
//! span·σ(raw)) as one fused op per activation on the CPU backends: one pass forward and
//! one backward, multi-threaded ([`cpu`]), where Burn's composed forms (softplus from five
//! element-wise ops, sigmoid as exp(−log1p(exp(−x))), each with its backward) run op by op on
//! one thread. Registered for NdArray, Flex and Autodiff over either; on wgpu the composed forms
//! run ([`activate`] chooses).

// The NdArray selector names burn-ndarray, deprecated in Burn 0.22 (Flex is its successor).
#![allow(deprecated)]

pub mod cpu;

use burn::backend::autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops},
};
use burn::backend::{Backend, Dispatch, backend_extension, tensor::FloatTensor};
use burn::tensor::Tensor;
use burn::tensor::activation::sigmoid;
use prism_kernel::autodiff::{backpropagate, inner, lift, record};

/// An element-wise activation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    /// `ln(1 + eˣ)`, evaluated as `max(x, 0) + ln(1 + e^{−|x|})` (no overflow).
    Softplus,
    /// `σ(x)·span + lo` (a value in `(lo, lo + span)`).
    Sigmoid { lo: f32, span: f32 },
}

/// The fused activation ops.
#[backend_extension(NdArray: cfg(feature = "ndarray"), Flex: cfg(feature = "flex"), Autodiff)]
pub trait ActivationOps: Backend {
    /// `kind` of every element of `x` (any shape).
    fn activate(x: FloatTensor<Self>, kind: Activation) -> FloatTensor<Self>;

    /// The gradient of `⟨grad, activate(x, kind)⟩` with respect to `x`.
    fn activate_backward(
        x: FloatTensor<Self>,
        kind: Activation,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

/// `kind` of every element of `x`: the fused op on the CPU backends, Burn's composed form on
/// wgpu.
pub fn activate<const D: usize>(x: Tensor<D>, kind: Activation) -> Tensor<D> {
    if prism_render::ops::is_gpu(&x.device()) {
        return composed(x, kind);
    }
    Tensor::from_dispatch(Dispatch::activate(x.into_dispatch(), kind))
}

/// [`activate`] composed of Burn ops.
pub fn composed<const D: usize>(x: Tensor<D>, kind: Activation) -> Tensor<D> {
    match kind {
        Activation::Softplus => x.clone().clamp_min(0.0) + x.abs().neg().exp().log1p(),
        Activation::Sigmoid { lo, span } => sigmoid(x) * span + lo,
    }
}

#[cfg(any(feature = "flex", feature = "ndarray"))]
mod backends {
    use prism_kernel::cpu::CpuFloat;

    macro_rules! impl_cpu_activation_ops {
        ($backend:ty) => {
            impl crate::gaussians::activation::ActivationOps for $backend {
                fn activate(
                    x: FloatTensor<Self>,
                    kind: crate::gaussians::activation::Activation,
                ) -> FloatTensor<Self> {
                    let y = Self::with_values([&x], |[x]| {
                        crate::gaussians::activation::cpu::forward(kind, x)
                    });
                    Self::tensor(y, Self::dims(&x))
                }

                fn activate_backward(
                    x: FloatTensor<Self>,
                    kind: crate::gaussians::activation::Activation,
                    grad: FloatTensor<Self>,
                ) -> FloatTensor<Self> {
                    let g = Self::with_values([&x, &grad], |[x, grad]| {
                        crate::gaussians::activation::cpu::backward(kind, x, grad)
                    });
                    Self::tensor(g, Self::dims(&x))
                }
            }
        };
    }

    #[cfg(feature = "flex")]
    mod flex {
        use super::*;
        use burn::backend::{Flex, tensor::FloatTensor};
        impl_cpu_activation_ops!(Flex);
    }

    // burn-ndarray is deprecated in Burn 0.22 (Flex is its successor); kept while it exists.
    #[cfg(feature = "ndarray")]
    mod ndarray {
        use super::*;
        use burn::backend::{NdArray, tensor::FloatTensor};
        impl_cpu_activation_ops!(NdArray);
    }
}

#[derive(Debug)]
struct ActivationBackward;

impl<B: ActivationOps> Backward<B, 1> for ActivationBackward {
    type State = (FloatTensor<B>, Activation);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 1>(ops, grads, |(x, kind), grad| {
            [B::activate_backward(x, kind, grad)]
        });
    }
}

impl<B: ActivationOps, C: CheckpointStrategy> ActivationOps for Autodiff<B, C> {
    fn activate(x: FloatTensor<Self>, kind: Activation) -> FloatTensor<Self> {
        record::<B, C, _, _, 1>(
            ActivationBackward,
            [x],
            |[x]| (x, kind),
            |[x]| B::activate(x, kind),
        )
    }

    fn activate_backward(
        x: FloatTensor<Self>,
        kind: Activation,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let [x, grad] = inner([x, grad]);
        let [g] = lift([B::activate_backward(x, kind, grad)]);
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::{cpu_device, host_values};
    use burn::tensor::TensorData;

    /// The fused op against the composed form (wgpu's) in value and gradient, on `[5, 7]`
    /// values over [−30, 30].
    #[test]
    fn fused_activations_match_the_composed_forms_and_their_gradients() {
        let ad = cpu_device().autodiff();
        let v: Vec<f32> = (0..35)
            .map(|i| -30.0 + 60.0 * (i as f32 / 34.0).powi(3))
            .collect();
        let g: Vec<f32> = (0..35).map(|i| ((i * 7) % 11) as f32 / 5.0 - 1.0).collect();
        let leaf =
            || Tensor::<2>::from_data(TensorData::new(v.clone(), [5, 7]), &ad).require_grad();
        let up = Tensor::<2>::from_data(TensorData::new(g, [5, 7]), &ad);
        for kind in [
            Activation::Softplus,
            Activation::Sigmoid {
                lo: 0.01,
                span: 0.49,
            },
        ] {
            let (xf, xc) = (leaf(), leaf());
            let (yf, yc) = (activate(xf.clone(), kind), composed(xc.clone(), kind));
            // Values to 2e-6 relative. The composed sigmoid's gradient σ(1 − σ) loses ulp(σ) to
            // cancellation in 1 − σ, an absolute error ≲ span·6e-8·|ḡ|, so gradients are held
            // to 1e-6 of their largest entry.
            let close = |a: &[f32], b: &[f32], what: &str| {
                let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                for (p, q) in a.iter().zip(b) {
                    let tol = if what == "value" {
                        2e-6 * q.abs().max(1e-3)
                    } else {
                        1e-6 * scale
                    };
                    assert!((p - q).abs() <= tol, "{kind:?} {what}: {p} vs {q}");
                }
            };
            close(&host_values(&yf), &host_values(&yc), "value");
            let gf = xf.grad(&(yf * up.clone()).sum().backward()).unwrap();
            let gc = xc.grad(&(yc * up.clone()).sum().backward()).unwrap();
            close(&host_values(&gf), &host_values(&gc), "gradient");
        }
    }
}
