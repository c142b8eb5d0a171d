//! The SSIM loss term as one fused op on the CPU backends: the mean SSIM of a batch of images
//! with a hand-written backward ([`cpu`]), where Burn's composed form (five blurs as
//! convolutions, a dozen element-wise ops, and their backward passes) runs op by op on one
//! thread. Registered for NdArray, Flex and Autodiff over either; on wgpu the composed form
//! runs ([`crate::gaussians::train::loss::SsimWindow::ssim`] chooses).

// The NdArray selector names burn-ndarray, deprecated in Burn 0.22 (Flex is its successor).
#![allow(deprecated)]

pub mod cpu;
pub mod window;

use burn::backend::autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops},
};
use burn::backend::{Backend, Dispatch, backend_extension, tensor::FloatTensor};
use burn::tensor::Tensor;
use prism_kernel::autodiff::{backpropagate, inner, lift, record};

/// The fused SSIM op. The target is data: it is not differentiated.
#[backend_extension(NdArray: cfg(feature = "ndarray"), Flex: cfg(feature = "flex"), Autodiff)]
pub trait SsimOps: Backend {
    /// Mean SSIM `[1]` over every image of `pred` and `target` (`[N, C, H, W]`, each of the N·C
    /// images on its own).
    fn ssim_mean(pred: FloatTensor<Self>, target: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The gradient of `grad · ssim_mean(pred, target)` with respect to `pred` (`grad`: `[1]`).
    fn ssim_mean_backward(
        pred: FloatTensor<Self>,
        target: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

/// Mean SSIM of `pred` against `target` (`[N, C, H, W]`) by the fused op; the caller checks the
/// device runs a CPU backend.
pub fn fused_ssim_mean(pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
    assert_eq!(pred.dims(), target.dims(), "ssim: shapes differ");
    Tensor::from_dispatch(Dispatch::ssim_mean(
        pred.into_dispatch(),
        target.into_dispatch(),
    ))
}

#[cfg(any(feature = "flex", feature = "ndarray"))]
mod backends {
    use prism_kernel::cpu::CpuFloat;

    /// `[N, C, H, W]` as N·C images.
    pub(super) fn dims(shape: &[usize]) -> super::cpu::Dims {
        let [n, c, h, w] = shape.try_into().expect("ssim takes [N, C, H, W] images");
        super::cpu::Dims {
            images: n * c,
            h,
            w,
        }
    }

    macro_rules! impl_cpu_ssim_ops {
        ($backend:ty) => {
            impl crate::gaussians::train::ssim::SsimOps for $backend {
                fn ssim_mean(
                    pred: FloatTensor<Self>,
                    target: FloatTensor<Self>,
                ) -> FloatTensor<Self> {
                    let d = dims(&Self::dims(&pred));
                    let s = Self::with_values([&pred, &target], |[p, t]| {
                        crate::gaussians::train::ssim::cpu::ssim_mean(d, p, t)
                    });
                    Self::tensor(vec![s], vec![1])
                }

                fn ssim_mean_backward(
                    pred: FloatTensor<Self>,
                    target: FloatTensor<Self>,
                    grad: FloatTensor<Self>,
                ) -> FloatTensor<Self> {
                    let shape = Self::dims(&pred);
                    let d = dims(&shape);
                    let g = Self::values(&grad)[0];
                    let out = Self::with_values([&pred, &target], |[p, t]| {
                        crate::gaussians::train::ssim::cpu::ssim_mean_backward(d, p, t, g)
                    });
                    Self::tensor(out, shape)
                }
            }
        };
    }

    #[cfg(feature = "flex")]
    mod flex {
        use super::*;
        use burn::backend::{Flex, tensor::FloatTensor};
        impl_cpu_ssim_ops!(Flex);
    }

    // burn-ndarray is deprecated in Burn 0.22 (Flex is its successor); kept while it exists.
    #[cfg(feature = "ndarray")]
    mod ndarray {
        use super::*;
        use burn::backend::{NdArray, tensor::FloatTensor};
        impl_cpu_ssim_ops!(NdArray);
    }
}

#[derive(Debug)]
struct SsimBackward;

impl<B: SsimOps> Backward<B, 1> for SsimBackward {
    /// The prediction and the target.
    type State = (FloatTensor<B>, FloatTensor<B>);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 1>(ops, grads, |(pred, target), grad| {
            [B::ssim_mean_backward(pred, target, grad)]
        });
    }
}

impl<B: SsimOps, C: CheckpointStrategy> SsimOps for Autodiff<B, C> {
    fn ssim_mean(pred: FloatTensor<Self>, target: FloatTensor<Self>) -> FloatTensor<Self> {
        // Only the prediction is on the graph: the target is data.
        let [target] = inner([target]);
        let keep = target.clone();
        record::<B, C, _, _, 1>(
            SsimBackward,
            [pred],
            |[pred]| (pred, keep),
            |[pred]| B::ssim_mean(pred, target),
        )
    }

    fn ssim_mean_backward(
        pred: FloatTensor<Self>,
        target: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let [pred, target, grad] = inner([pred, target, grad]);
        let [g] = lift([B::ssim_mean_backward(pred, target, grad)]);
        g
    }
}
