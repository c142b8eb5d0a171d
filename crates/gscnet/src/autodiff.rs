//! Autodiff registration of [`SpectralOps`]: the forward ops save their (inner-backend) inputs,
//! the backward step calls the backend's `*_backward` op once and registers the gradient of
//! every tracked input. The backward ops are not themselves differentiated.

use burn::backend::{
    AutodiffBackend,
    autodiff::{
        Autodiff,
        checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
        grads::Gradients,
        ops::{Backward, Ops, OpsKind},
    },
    tensor::FloatTensor,
};

use crate::ops::SpectralOps;

#[derive(Debug)]
struct ScanBackward;

impl<B: SpectralOps> Backward<B, 6> for ScanBackward {
    type State = ([FloatTensor<B>; 6], bool);

    fn backward(self, ops: Ops<Self::State, 6>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let ([x, delta, a_log, b, c, d], softplus) = ops.state;
        let (g0, g1, g2, g3, g4, g5) =
            B::selective_scan_backward(x, delta, a_log, b, c, d, softplus, grad);
        for (parent, g) in ops.parents.into_iter().zip([g0, g1, g2, g3, g4, g5]) {
            if let Some(node) = parent {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

#[derive(Debug)]
struct ConvBackward;

impl<B: SpectralOps> Backward<B, 3> for ConvBackward {
    type State = [FloatTensor<B>; 3];

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let [u, w, bias] = ops.state;
        let (g0, g1, g2) = B::spectral_conv_silu_backward(u, w, bias, grad);
        for (parent, g) in ops.parents.into_iter().zip([g0, g1, g2]) {
            if let Some(node) = parent {
                grads.register::<B>(node.id, g);
            }
        }
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
        let prep = ScanBackward
            .prepare::<C>([
                x.node(),
                delta.node(),
                a_log.node(),
                b.node(),
                c.node(),
                d.node(),
            ])
            .compute_bound()
            .stateful();
        let inputs = [
            x.into_primitive(),
            delta.into_primitive(),
            a_log.into_primitive(),
            b.into_primitive(),
            c.into_primitive(),
            d.into_primitive(),
        ];
        match prep {
            OpsKind::Tracked(prep) => {
                let [x, delta, a_log, b, c, d] = inputs.clone();
                let out = B::selective_scan(x, delta, a_log, b, c, d, softplus);
                prep.finish((inputs, softplus), out)
            }
            OpsKind::UnTracked(prep) => {
                let [x, delta, a_log, b, c, d] = inputs;
                prep.finish(B::selective_scan(x, delta, a_log, b, c, d, softplus))
            }
        }
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
        let (g0, g1, g2, g3, g4, g5) = B::selective_scan_backward(
            x.into_primitive(),
            delta.into_primitive(),
            a_log.into_primitive(),
            b.into_primitive(),
            c.into_primitive(),
            d.into_primitive(),
            softplus,
            grad.into_primitive(),
        );
        let lift = <Self as AutodiffBackend>::from_inner;
        (lift(g0), lift(g1), lift(g2), lift(g3), lift(g4), lift(g5))
    }

    fn spectral_conv_silu(
        u: FloatTensor<Self>,
        w: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let prep = ConvBackward
            .prepare::<C>([u.node(), w.node(), bias.node()])
            .compute_bound()
            .stateful();
        let inputs = [
            u.into_primitive(),
            w.into_primitive(),
            bias.into_primitive(),
        ];
        match prep {
            OpsKind::Tracked(prep) => {
                let [u, w, bias] = inputs.clone();
                let out = B::spectral_conv_silu(u, w, bias);
                prep.finish(inputs, out)
            }
            OpsKind::UnTracked(prep) => {
                let [u, w, bias] = inputs;
                prep.finish(B::spectral_conv_silu(u, w, bias))
            }
        }
    }

    fn spectral_conv_silu_backward(
        u: FloatTensor<Self>,
        w: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let (g0, g1, g2) = B::spectral_conv_silu_backward(
            u.into_primitive(),
            w.into_primitive(),
            bias.into_primitive(),
            grad.into_primitive(),
        );
        let lift = <Self as AutodiffBackend>::from_inner;
        (lift(g0), lift(g1), lift(g2))
    }
}
