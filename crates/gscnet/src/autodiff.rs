//! Autodiff registration of [`SpectralOps`]: the hand-written backward kernels as Burn
//! `Backward` steps (the pattern is [`prism_kernel::autodiff`]'s).

use burn::backend::autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops},
};
use burn::backend::tensor::FloatTensor;
use prism_kernel::autodiff::{backpropagate, inner, lift, record};

use crate::ops::SpectralOps;

#[derive(Debug)]
struct ScanBackward;

impl<B: SpectralOps> Backward<B, 6> for ScanBackward {
    type State = ([FloatTensor<B>; 6], bool);

    fn backward(self, ops: Ops<Self::State, 6>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 6>(
            ops,
            grads,
            |([x, delta, a_log, b, c, d], softplus), grad| {
                let (g0, g1, g2, g3, g4, g5) =
                    B::selective_scan_backward(x, delta, a_log, b, c, d, softplus, grad);
                [g0, g1, g2, g3, g4, g5]
            },
        );
    }
}

#[derive(Debug)]
struct ConvBackward;

impl<B: SpectralOps> Backward<B, 3> for ConvBackward {
    type State = [FloatTensor<B>; 3];

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 3>(ops, grads, |[u, w, bias], grad| {
            let (g0, g1, g2) = B::spectral_conv_silu_backward(u, w, bias, grad);
            [g0, g1, g2]
        });
    }
}

impl<B: SpectralOps, C: CheckpointStrategy> SpectralOps for Autodiff<B, C> {
    fn selective_scan(
        x: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        a_log: FloatTensor<Self>,
        b: FloatTensor<Self>,
        c: FloatTensor<Self>,
        d: FloatTensor<Self>,
        softplus: bool,
    ) -> FloatTensor<Self> {
        record::<B, C, _, _, 6>(
            ScanBackward,
            [x, delta, a_log, b, c, d],
            |inputs| (inputs, softplus),
            |[x, delta, a_log, b, c, d]| B::selective_scan(x, delta, a_log, b, c, d, softplus),
        )
    }

    fn selective_scan_backward(
        x: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        a_log: FloatTensor<Self>,
        b: FloatTensor<Self>,
        c: FloatTensor<Self>,
        d: FloatTensor<Self>,
        softplus: bool,
        grad: FloatTensor<Self>,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    ) {
        let [x, delta, a_log, b, c, d, grad] = inner([x, delta, a_log, b, c, d, grad]);
        let (g0, g1, g2, g3, g4, g5) =
            B::selective_scan_backward(x, delta, a_log, b, c, d, softplus, grad);
        let [g0, g1, g2, g3, g4, g5] = lift([g0, g1, g2, g3, g4, g5]);
        (g0, g1, g2, g3, g4, g5)
    }

    fn spectral_conv_silu(
        u: FloatTensor<Self>,
        w: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        record::<B, C, _, _, 3>(
            ConvBackward,
            [u, w, bias],
            |inputs| inputs,
            |[u, w, bias]| B::spectral_conv_silu(u, w, bias),
        )
    }

    fn spectral_conv_silu_backward(
        u: FloatTensor<Self>,
        w: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let [u, w, bias, grad] = inner([u, w, bias, grad]);
        let (g0, g1, g2) = B::spectral_conv_silu_backward(u, w, bias, grad);
        let [g0, g1, g2] = lift([g0, g1, g2]);
        (g0, g1, g2)
    }
}
