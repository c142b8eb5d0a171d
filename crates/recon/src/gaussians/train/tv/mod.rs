//! The total-variation loss term as one fused op on the CPU backends: value and gradient each
//! one multi-threaded pass ([`cpu`]), where Burn's composed form (narrows, differences,
//! absolute values and sums per axis, and their backward passes) runs op by op on one thread.
//! Registered for NdArray, Flex and Autodiff over either; on wgpu the composed form runs
//! ([`crate::gaussians::train::loss::total_variation`] chooses).

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
use prism_kernel::autodiff::{backpropagate, inner, lift, record};

/// The fused total-variation op.
#[backend_extension(NdArray: cfg(feature = "ndarray"), Flex: cfg(feature = "flex"), Autodiff)]
pub trait TvOps: Backend {
    /// `TV` `[1]` of `v` `[M, Z, Y, X]` ([`cpu::total_variation`]).
    fn total_variation(v: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The gradient of `grad · TV(v)` with respect to `v` (`grad`: `[1]`).
    fn total_variation_backward(v: FloatTensor<Self>, grad: FloatTensor<Self>)
    -> FloatTensor<Self>;
}

/// `TV` of `v` `[M, Z, Y, X]` by the fused op; the caller checks the device runs a CPU backend.
pub fn fused_total_variation(v: Tensor<4>) -> Tensor<1> {
    Tensor::from_dispatch(Dispatch::total_variation(v.into_dispatch()))
}

#[cfg(any(feature = "flex", feature = "ndarray"))]
mod backends {
    macro_rules! impl_cpu_tv_ops {
        ($backend:ty) => {
            impl crate::gaussians::train::tv::TvOps for $backend {
                fn total_variation(v: FloatTensor<Self>) -> FloatTensor<Self> {
                    let d = crate::gaussians::train::tv::cpu::Dims::of(&Self::dims(&v));
                    let tv = Self::with_values([&v], |[v]| {
                        crate::gaussians::train::tv::cpu::total_variation(d, v)
                    });
                    Self::tensor(vec![tv], vec![1])
                }

                fn total_variation_backward(
                    v: FloatTensor<Self>,
                    grad: FloatTensor<Self>,
                ) -> FloatTensor<Self> {
                    let shape = Self::dims(&v);
                    let d = crate::gaussians::train::tv::cpu::Dims::of(&shape);
                    let g = Self::values(&grad)[0];
                    let out = Self::with_values([&v], |[v]| {
                        crate::gaussians::train::tv::cpu::total_variation_backward(d, v, g)
                    });
                    Self::tensor(out, shape)
                }
            }
        };
    }

    #[cfg(feature = "flex")]
    mod flex {
        use burn::backend::{Flex, tensor::FloatTensor};
        use prism_kernel::cpu::CpuFloat;
        impl_cpu_tv_ops!(Flex);
    }

    // burn-ndarray is deprecated in Burn 0.22 (Flex is its successor); kept while it exists.
    #[cfg(feature = "ndarray")]
    mod ndarray {
        use burn::backend::{NdArray, tensor::FloatTensor};
        use prism_kernel::cpu::CpuFloat;
        impl_cpu_tv_ops!(NdArray);
    }
}

#[derive(Debug)]
struct TvBackward;

impl<B: TvOps> Backward<B, 1> for TvBackward {
    /// The volumes.
    type State = FloatTensor<B>;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 1>(ops, grads, |v, grad| [B::total_variation_backward(v, grad)]);
    }
}

impl<B: TvOps, C: CheckpointStrategy> TvOps for Autodiff<B, C> {
    fn total_variation(v: FloatTensor<Self>) -> FloatTensor<Self> {
        record::<B, C, _, _, 1>(TvBackward, [v], |[v]| v, |[v]| B::total_variation(v))
    }

    fn total_variation_backward(
        v: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let [v, grad] = inner([v, grad]);
        let [g] = lift([B::total_variation_backward(v, grad)]);
        g
    }
}
