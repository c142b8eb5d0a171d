//! Autodiff registration: the hand-written backward kernels as Burn `Backward` steps (the
//! pattern is [`prism_kernel::autodiff`]'s).
//!
//! The projection also saves its prepared state (see
//! [`GaussianOps::gaussian_project_prepare`]), so the backward reuses the forward's per-Gaussian
//! preparation. The prepared state is not differentiated.

use burn::backend::autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops},
};
use burn::backend::tensor::FloatTensor;
use prism_kernel::autodiff::{backpropagate, inner, lift, record};

use crate::camera::Camera;
use crate::ops::GaussianOps;
use crate::options::{ProjectOptions, VoxelGrid, VoxelizeOptions};

#[derive(Debug)]
struct ProjectBackward;

/// The five differentiable inputs, the prepared state, cameras and options.
type ProjectState<B> = (
    [FloatTensor<B>; 5],
    FloatTensor<B>,
    Vec<Camera>,
    ProjectOptions,
);

impl<B: GaussianOps> Backward<B, 5> for ProjectBackward {
    type State = ProjectState<B>;

    fn backward(self, ops: Ops<Self::State, 5>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 5>(ops, grads, |(x, prepared, cameras, options), grad| {
            let [means, scales, rotations, densities, screen] = x;
            let (a, b, c, d, e) = B::gaussian_project_backward(
                means, scales, rotations, densities, screen, prepared, cameras, options, grad,
            );
            [a, b, c, d, e]
        });
    }
}

#[derive(Debug)]
struct VoxelizeBackward;

impl<B: GaussianOps> Backward<B, 4> for VoxelizeBackward {
    type State = ([FloatTensor<B>; 4], VoxelGrid, VoxelizeOptions);

    fn backward(self, ops: Ops<Self::State, 4>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 4>(ops, grads, |(x, grid, options), grad| {
            let [means, scales, rotations, densities] = x;
            let (a, b, c, d) = B::gaussian_voxelize_backward(
                means, scales, rotations, densities, grid, options, grad,
            );
            [a, b, c, d]
        });
    }
}

impl<B: GaussianOps, C: CheckpointStrategy> GaussianOps for Autodiff<B, C> {
    fn gaussian_project_prepare(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let [means, scales, rotations, densities, screen] =
            inner([means, scales, rotations, densities, screen]);
        let prepared = B::gaussian_project_prepare(
            means, scales, rotations, densities, screen, cameras, options,
        );
        let [prepared] = lift([prepared]);
        prepared
    }

    fn gaussian_project(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let prepared = prepared.into_primitive();
        let saved = (prepared.clone(), cameras.clone(), options);
        record::<B, C, _, _, 5>(
            ProjectBackward,
            [means, scales, rotations, densities, screen],
            move |x| (x, saved.0, saved.1, saved.2),
            |[a, b, c, d, e]| B::gaussian_project(a, b, c, d, e, prepared, cameras, options),
        )
    }

    fn gaussian_project_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
        grad: FloatTensor<Self>,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    ) {
        let [means, scales, rotations, densities, screen, prepared, grad] =
            inner([means, scales, rotations, densities, screen, prepared, grad]);
        let (a, b, c, d, e) = B::gaussian_project_backward(
            means, scales, rotations, densities, screen, prepared, cameras, options, grad,
        );
        let [a, b, c, d, e] = lift([a, b, c, d, e]);
        (a, b, c, d, e)
    }

    fn gaussian_voxelize(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
    ) -> FloatTensor<Self> {
        record::<B, C, _, _, 4>(
            VoxelizeBackward,
            [means, scales, rotations, densities],
            |x| (x, grid, options),
            |[a, b, c, d]| B::gaussian_voxelize(a, b, c, d, grid, options),
        )
    }

    fn gaussian_voxelize_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
        grad: FloatTensor<Self>,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    ) {
        let [means, scales, rotations, densities, grad] =
            inner([means, scales, rotations, densities, grad]);
        let (a, b, c, d) =
            B::gaussian_voxelize_backward(means, scales, rotations, densities, grid, options, grad);
        let [a, b, c, d] = lift([a, b, c, d]);
        (a, b, c, d)
    }
}
