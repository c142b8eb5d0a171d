//! Custom ops on Burn's autodiff graph, with hand-written backward passes.
//!
//! A differentiable op implements Burn's [`Backward`] step: [`record`] runs the inner backend's
//! forward and, when any input is tracked, saves what the backward needs; in the step's
//! `backward`, [`backpropagate`] hands the output gradient to the inner backend's backward op and
//! registers the gradient of every tracked input. Backward ops themselves are not differentiated
//! (no double backward).

use burn::backend::Backend;
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use std::fmt::Debug;

/// Run `forward` on the inner values of `inputs` and record the op on the autodiff graph with the
/// backward step `step`; when an input is tracked, `state` (called on the same inner values)
/// builds what the step keeps for its backward pass. The checkpointing strategy `C` is not
/// visible in the tensor type: call it as `record::<B, C, _, _, N>(..)`.
pub fn record<B, C, BO, S, const N: usize>(
    step: BO,
    inputs: [FloatTensor<Autodiff<B, C>>; N],
    state: impl FnOnce([FloatTensor<B>; N]) -> S,
    forward: impl FnOnce([FloatTensor<B>; N]) -> FloatTensor<B>,
) -> FloatTensor<Autodiff<B, C>>
where
    B: Backend,
    C: CheckpointStrategy,
    BO: Backward<B, N, State = S>,
    S: Clone + Send + Debug + 'static,
{
    let nodes = inputs.each_ref().map(|t| t.node());
    let prep = step.prepare::<C>(nodes).compute_bound().stateful();
    let inner = inputs.map(|t| t.into_primitive());
    match prep {
        OpsKind::Tracked(prep) => {
            let out = forward(inner.clone());
            prep.finish(state(inner), out)
        }
        OpsKind::UnTracked(prep) => prep.finish(forward(inner)),
    }
}

/// The body of a [`Backward::backward`]: take the output's gradient, let `backward` turn it (with
/// the saved state) into one gradient per input, and register those of tracked inputs.
pub fn backpropagate<B: Backend, S, const N: usize>(
    ops: Ops<S, N>,
    grads: &mut Gradients,
    backward: impl FnOnce(S, FloatTensor<B>) -> [FloatTensor<B>; N],
) {
    let grad = grads.consume::<B>(&ops.node);
    let input_grads = backward(ops.state, grad);
    for (parent, g) in ops.parents.into_iter().zip(input_grads) {
        if let Some(node) = parent {
            grads.register::<B>(node.id, g);
        }
    }
}

/// The inner backend's values of autodiff tensors (for ops that are not differentiated). The
/// autodiff tensor type does not depend on the checkpointing strategy.
pub fn inner<B: Backend, const N: usize>(ts: [FloatTensor<Autodiff<B>>; N]) -> [FloatTensor<B>; N] {
    ts.map(|t| t.into_primitive())
}

/// Autodiff tensors (untracked) holding inner values, e.g. a backward op's results.
pub fn lift<B: Backend, const N: usize>(ts: [FloatTensor<B>; N]) -> [FloatTensor<Autodiff<B>>; N] {
    ts.map(<Autodiff<B> as burn::backend::AutodiffBackend>::from_inner)
}
