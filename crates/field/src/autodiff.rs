//! Autodiff registration of [`FieldOps`]: the table is the tracked input, the points are
//! kept (untracked) for the backward scatter.

use burn::backend::autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops},
};
use burn::backend::tensor::FloatTensor;
use prism_kernel::autodiff::{backpropagate, inner, lift, record};

use crate::grid::HashGrid;
use crate::mlp::MlpLayout;
use crate::ops::FieldOps;

#[derive(Debug)]
struct EncodeBackward;

impl<B: FieldOps> Backward<B, 1> for EncodeBackward {
    type State = (FloatTensor<B>, HashGrid);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 1>(ops, grads, |(points, grid), grad| {
            [B::hash_grid_encode_backward(points, grid, grad)]
        });
    }
}

#[derive(Debug)]
struct MlpBackward;

impl<B: FieldOps> Backward<B, 2> for MlpBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, MlpLayout);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 2>(ops, grads, |(enc, params, layout), grad| {
            let (d_enc, d_params) = B::field_mlp_backward(enc, params, layout, grad);
            [d_enc, d_params]
        });
    }
}

impl<B: FieldOps, C: CheckpointStrategy> FieldOps for Autodiff<B, C> {
    fn hash_grid_encode(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        let points = points.into_primitive();
        let kept = (points.clone(), grid.clone());
        record::<B, C, _, _, 1>(
            EncodeBackward,
            [table],
            |_| kept,
            |[table]| B::hash_grid_encode(points, table, grid),
        )
    }

    fn hash_grid_encode_backward(
        points: FloatTensor<Self>,
        grid: HashGrid,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let [points, grad] = inner([points, grad]);
        let [g] = lift([B::hash_grid_encode_backward(points, grid, grad)]);
        g
    }

    fn field_mlp(
        enc: FloatTensor<Self>,
        params: FloatTensor<Self>,
        layout: MlpLayout,
    ) -> FloatTensor<Self> {
        record::<B, C, _, _, 2>(
            MlpBackward,
            [enc, params],
            |[enc, params]| (enc, params, layout),
            |[enc, params]| B::field_mlp(enc, params, layout),
        )
    }

    fn field_mlp_backward(
        enc: FloatTensor<Self>,
        params: FloatTensor<Self>,
        layout: MlpLayout,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let [enc, params, grad] = inner([enc, params, grad]);
        let (d_enc, d_params) = B::field_mlp_backward(enc, params, layout, grad);
        let [d_enc, d_params] = lift([d_enc, d_params]);
        (d_enc, d_params)
    }
}
