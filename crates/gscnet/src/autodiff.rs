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

use crate::ops::{Activation, ScanTensors, SpectralOps};

#[derive(Debug)]
struct ScanBackward;

impl<B: SpectralOps> Backward<B, 6> for ScanBackward {
    type State = ([FloatTensor<B>; 6], bool);

    fn backward(self, ops: Ops<Self::State, 6>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 6>(ops, grads, |(inputs, softplus), grad| {
            B::selective_scan_backward(ScanTensors::from_array(inputs), softplus, grad).into_array()
        });
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

#[derive(Debug)]
struct TableBackward;

impl<B: SpectralOps> Backward<B, 2> for TableBackward {
    type State = ([FloatTensor<B>; 2], f32);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 2>(ops, grads, |([table, u], h), grad| {
            let (gt, gu) = B::table_lookup_backward(table, u, h, grad);
            [gt, gu]
        });
    }
}

#[derive(Debug)]
struct ActivationBackward;

impl<B: SpectralOps> Backward<B, 1> for ActivationBackward {
    type State = (FloatTensor<B>, Activation);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 1>(ops, grads, |(x, kind), grad| {
            [B::activate_backward(x, kind, grad)]
        });
    }
}

impl<B: SpectralOps, C: CheckpointStrategy> SpectralOps for Autodiff<B, C> {
    fn selective_scan(inputs: ScanTensors<Self>, softplus: bool) -> FloatTensor<Self> {
        record::<B, C, _, _, 6>(
            ScanBackward,
            inputs.into_array(),
            |inputs| (inputs, softplus),
            |inputs| B::selective_scan(ScanTensors::from_array(inputs), softplus),
        )
    }

    fn selective_scan_backward(
        inputs: ScanTensors<Self>,
        softplus: bool,
        grad: FloatTensor<Self>,
    ) -> ScanTensors<Self> {
        let inputs = ScanTensors::from_array(inner(inputs.into_array()));
        let [grad] = inner([grad]);
        let g = B::selective_scan_backward(inputs, softplus, grad);
        ScanTensors::from_array(lift(g.into_array()))
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

    fn table_lookup(table: FloatTensor<Self>, u: FloatTensor<Self>, h: f32) -> FloatTensor<Self> {
        record::<B, C, _, _, 2>(
            TableBackward,
            [table, u],
            |inputs| (inputs, h),
            |[table, u]| B::table_lookup(table, u, h),
        )
    }

    fn table_lookup_backward(
        table: FloatTensor<Self>,
        u: FloatTensor<Self>,
        h: f32,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let [table, u, grad] = inner([table, u, grad]);
        let (gt, gu) = B::table_lookup_backward(table, u, h, grad);
        let [gt, gu] = lift([gt, gu]);
        (gt, gu)
    }

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
