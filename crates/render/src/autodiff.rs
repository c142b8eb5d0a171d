//! Autodiff registration: the hand-written backward kernels as Burn `Backward` steps.
//!
//! The forward ops save their (inner-backend) inputs; the backward step calls the backend's
//! `*_backward` op once and registers the gradient of every tracked input. The projection also
//! saves its prepared state (see [`GaussianOps::gaussian_project_prepare`]), so the backward
//! reuses the forward's per-Gaussian preparation. The backward ops themselves are not
//! differentiated (no double backward), nor is the prepared state.

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
        let grad = grads.consume::<B>(&ops.node);
        let ([means, scales, rotations, densities, screen], prepared, cameras, options) = ops.state;
        let (g0, g1, g2, g3, g4) = B::gaussian_project_backward(
            means, scales, rotations, densities, screen, prepared, cameras, options, grad,
        );
        for (parent, g) in ops.parents.into_iter().zip([g0, g1, g2, g3, g4]) {
            if let Some(node) = parent {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

#[derive(Debug)]
struct VoxelizeBackward;

impl<B: GaussianOps> Backward<B, 4> for VoxelizeBackward {
    type State = ([FloatTensor<B>; 4], VoxelGrid, VoxelizeOptions);

    fn backward(self, ops: Ops<Self::State, 4>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let ([means, scales, rotations, densities], grid, options) = ops.state;
        let (g0, g1, g2, g3) =
            B::gaussian_voxelize_backward(means, scales, rotations, densities, grid, options, grad);
        for (parent, g) in ops.parents.into_iter().zip([g0, g1, g2, g3]) {
            if let Some(node) = parent {
                grads.register::<B>(node.id, g);
            }
        }
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
        let prepared = B::gaussian_project_prepare(
            means.into_primitive(),
            scales.into_primitive(),
            rotations.into_primitive(),
            densities.into_primitive(),
            screen.into_primitive(),
            cameras,
            options,
        );
        <Self as AutodiffBackend>::from_inner(prepared)
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
        let prep = ProjectBackward
            .prepare::<C>([
                means.node(),
                scales.node(),
                rotations.node(),
                densities.node(),
                screen.node(),
            ])
            .compute_bound()
            .stateful();
        let inputs = [
            means.into_primitive(),
            scales.into_primitive(),
            rotations.into_primitive(),
            densities.into_primitive(),
            screen.into_primitive(),
        ];
        let prepared = prepared.into_primitive();
        match prep {
            OpsKind::Tracked(prep) => {
                let [a, b, c, d, e] = inputs.clone();
                let out =
                    B::gaussian_project(a, b, c, d, e, prepared.clone(), cameras.clone(), options);
                prep.finish((inputs, prepared, cameras, options), out)
            }
            OpsKind::UnTracked(prep) => {
                let [a, b, c, d, e] = inputs;
                prep.finish(B::gaussian_project(
                    a, b, c, d, e, prepared, cameras, options,
                ))
            }
        }
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
        let (a, b, c, d, e) = B::gaussian_project_backward(
            means.into_primitive(),
            scales.into_primitive(),
            rotations.into_primitive(),
            densities.into_primitive(),
            screen.into_primitive(),
            prepared.into_primitive(),
            cameras,
            options,
            grad.into_primitive(),
        );
        let lift = <Self as AutodiffBackend>::from_inner;
        (lift(a), lift(b), lift(c), lift(d), lift(e))
    }

    fn gaussian_voxelize(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
    ) -> FloatTensor<Self> {
        let prep = VoxelizeBackward
            .prepare::<C>([
                means.node(),
                scales.node(),
                rotations.node(),
                densities.node(),
            ])
            .compute_bound()
            .stateful();
        let inputs = [
            means.into_primitive(),
            scales.into_primitive(),
            rotations.into_primitive(),
            densities.into_primitive(),
        ];
        match prep {
            OpsKind::Tracked(prep) => {
                let [a, b, c, d] = inputs.clone();
                let out = B::gaussian_voxelize(a, b, c, d, grid, options);
                prep.finish((inputs, grid, options), out)
            }
            OpsKind::UnTracked(prep) => {
                let [a, b, c, d] = inputs;
                prep.finish(B::gaussian_voxelize(a, b, c, d, grid, options))
            }
        }
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
        let (a, b, c, d) = B::gaussian_voxelize_backward(
            means.into_primitive(),
            scales.into_primitive(),
            rotations.into_primitive(),
            densities.into_primitive(),
            grid,
            options,
            grad.into_primitive(),
        );
        let lift = <Self as AutodiffBackend>::from_inner;
        (lift(a), lift(b), lift(c), lift(d))
    }
}
