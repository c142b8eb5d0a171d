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
use burn::backend::{Backend, tensor::FloatTensor};
use prism_kernel::autodiff::{backpropagate, inner, lift, record};

use crate::camera::Camera;
use crate::ops::{GaussianOps, GaussianTensors};
use crate::options::{ProjectOptions, VoxelGrid, VoxelizeOptions};

#[derive(Debug)]
struct ProjectBackward;

/// The five differentiable inputs (means, scales, rotations, densities, screen), the prepared
/// state, cameras and options.
type ProjectState<B> = (
    [FloatTensor<B>; 5],
    FloatTensor<B>,
    Vec<Camera>,
    ProjectOptions,
);

/// The differentiable inputs of a projection as one array: the Gaussians, then the screen offsets.
fn with_screen<B: Backend>(
    gaussians: GaussianTensors<B>,
    screen: FloatTensor<B>,
) -> [FloatTensor<B>; 5] {
    let [means, scales, rotations, densities] = gaussians.into_array();
    [means, scales, rotations, densities, screen]
}

/// The inverse of [`with_screen`].
fn split_screen<B: Backend>(
    [means, scales, rotations, densities, screen]: [FloatTensor<B>; 5],
) -> (GaussianTensors<B>, FloatTensor<B>) {
    (
        GaussianTensors::from_array([means, scales, rotations, densities]),
        screen,
    )
}

impl<B: GaussianOps> Backward<B, 5> for ProjectBackward {
    type State = ProjectState<B>;

    fn backward(self, ops: Ops<Self::State, 5>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 5>(ops, grads, |(x, prepared, cameras, options), grad| {
            let (gaussians, screen) = split_screen(x);
            let (g, g_screen) =
                B::gaussian_project_backward(gaussians, screen, prepared, cameras, options, grad);
            with_screen(g, g_screen)
        });
    }
}

#[derive(Debug)]
struct VoxelizeBackward;

impl<B: GaussianOps> Backward<B, 4> for VoxelizeBackward {
    type State = ([FloatTensor<B>; 4], VoxelGrid, VoxelizeOptions);

    fn backward(self, ops: Ops<Self::State, 4>, grads: &mut Gradients, _ck: &mut Checkpointer) {
        backpropagate::<B, _, 4>(ops, grads, |(x, grid, options), grad| {
            B::gaussian_voxelize_backward(GaussianTensors::from_array(x), grid, options, grad)
                .into_array()
        });
    }
}

impl<B: GaussianOps, C: CheckpointStrategy> GaussianOps for Autodiff<B, C> {
    fn gaussian_project_prepare(
        gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let (gaussians, screen) = split_screen(inner(with_screen(gaussians, screen)));
        let prepared = B::gaussian_project_prepare(gaussians, screen, cameras, options);
        let [prepared] = lift([prepared]);
        prepared
    }

    fn gaussian_project(
        gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let prepared = prepared.into_primitive();
        let saved = (prepared.clone(), cameras.clone(), options);
        record::<B, C, _, _, 5>(
            ProjectBackward,
            with_screen(gaussians, screen),
            move |x| (x, saved.0, saved.1, saved.2),
            |x| {
                let (gaussians, screen) = split_screen(x);
                B::gaussian_project(gaussians, screen, prepared, cameras, options)
            },
        )
    }

    fn gaussian_project_backward(
        gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
        grad: FloatTensor<Self>,
    ) -> (GaussianTensors<Self>, FloatTensor<Self>) {
        let [prepared, grad] = inner([prepared, grad]);
        let (gaussians, screen) = split_screen(inner(with_screen(gaussians, screen)));
        let (g, g_screen) =
            B::gaussian_project_backward(gaussians, screen, prepared, cameras, options, grad);
        split_screen(lift(with_screen(g, g_screen)))
    }

    fn gaussian_voxelize(
        gaussians: GaussianTensors<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
    ) -> FloatTensor<Self> {
        record::<B, C, _, _, 4>(
            VoxelizeBackward,
            gaussians.into_array(),
            |x| (x, grid, options),
            |x| B::gaussian_voxelize(GaussianTensors::from_array(x), grid, options),
        )
    }

    fn gaussian_voxelize_backward(
        gaussians: GaussianTensors<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
        grad: FloatTensor<Self>,
    ) -> GaussianTensors<Self> {
        let gaussians = GaussianTensors::from_array(inner(gaussians.into_array()));
        let [grad] = inner([grad]);
        let g = B::gaussian_voxelize_backward(gaussians, grid, options, grad);
        GaussianTensors::from_array(lift(g.into_array()))
    }
}
