//! CubeCL kernels of the render ops for Burn's `CubeBackend` (wgpu: Vulkan, Metal, DX12, and
//! Mesa's lavapipe without a GPU).
//!
//! Same contract as the CPU kernels ([`crate::cpu`]): culling and cut-off rules are the same,
//! and every formula is the f32 port of [`crate::gaussian_math`] ([`math`], on the typed values
//! of [`types`]). The prepared projection state is this backend's own records
//! ([`project::AffineRecord`], which has the CPU's layout, and [`exact::ExactRecord`];
//! [`layout::prepared_width`]). Forward passes own one output tile per cube and compact the tile's
//! Gaussians in index order ([`culling::stage_chunk`]); backward passes own one Gaussian per unit
//! and gather its footprint. Neither needs atomics, so the kernels run unchanged on devices
//! without f32 atomic add and give run-to-run identical results. Nothing is read back to the
//! host: every buffer size follows from the shapes.
//!
//! Forward kernels skip whole culling steps whose union box ([`culling::step_bounds_kernel`])
//! misses the cube's tile or brick, which pays when consecutive Gaussians are spatially close.

// Kernels reject NaN through negated comparisons (`!(x > 0)` is true for NaN); CubeCL has no
// `partial_cmp`, nor `div_ceil`.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::manual_div_ceil)]

pub mod culling;
pub mod exact;
mod host;
pub mod layout;
pub mod math;
pub mod project;
pub mod types;
pub mod voxelize;

#[cfg(test)]
mod tests;

pub use culling::{CHUNK, PER_UNIT, STEP, stage_chunk, step_bounds_kernel};
pub use host::pack_cameras;
use layout::prepared_width;

use burn::backend::tensor::FloatTensor;
use burn_cubecl::cubecl;
use burn_cubecl::{CubeBackend, kernel::into_contiguous};
use cubecl::prelude::*;

use crate::camera::Camera;
use crate::ops::GaussianTensors;
use crate::options::{ProjectOptions, ProjectionMode, VoxelGrid, VoxelizeOptions};
use culling::{AFFINE_BOXES, EXACT_BOXES, VOXEL_BOXES, step_bounds};
use host::{
    Params, dims, grid_record, linear, project_uniforms, upload, voxel_prepare, voxelize_uniforms,
    zero_grads, zeros,
};
use project::TILE;

impl crate::ops::GaussianOps for CubeBackend {
    fn gaussian_project_prepare(
        gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let p = Params::new(gaussians);
        let exact = options.mode == ProjectionMode::Exact;
        let out = zeros(
            &p.g.means,
            vec![cameras.len(), p.k, prepared_width(options.mode)],
        );
        if cameras.is_empty() || p.k == 0 {
            return out;
        }
        let cams = upload(&p.g.means, pack_cameras(&cameras));
        let (count, dim) = linear(p.k * cameras.len());
        let uniforms = project_uniforms(p.k, &cameras, &options);
        if exact {
            exact::prepare_exact_kernel::launch(
                &p.g.means.client,
                count,
                dim,
                p.launch_arg(),
                into_contiguous(screen).into_tensor_arg(),
                cams.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                uniforms,
                p.m,
            );
            return out;
        }
        project::prepare_kernel::launch(
            &p.g.means.client,
            count,
            dim,
            p.launch_arg(),
            into_contiguous(screen).into_tensor_arg(),
            cams.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            uniforms,
            p.m,
        );
        out
    }

    fn gaussian_project(
        gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let GaussianTensors {
            means, densities, ..
        } = gaussians;
        let _ = screen;
        let exact = options.mode == ProjectionMode::Exact;
        let k = dims(&means)[0];
        let m = dims(&densities)[1];
        let (rows, cols) = cameras.first().map_or((0, 0), |c| (c.rows, c.cols));
        let out = zeros(&means, vec![cameras.len(), m, rows, cols]);
        if k == 0 || m == 0 || rows == 0 || cols == 0 {
            return out;
        }
        let prepared = into_contiguous(prepared);
        let layout = if exact { EXACT_BOXES } else { AFFINE_BOXES };
        let bounds = step_bounds(&prepared, k, cameras.len(), layout);
        let cams = upload(&means, pack_cameras(&cameras));
        let count = CubeCount::Static(
            (cols as u32).div_ceil(TILE),
            (rows as u32).div_ceil(TILE),
            cameras.len() as u32,
        );
        project::forward_kernel::launch(
            &means.client,
            count,
            CubeDim::new_2d(TILE, TILE),
            prepared.into_tensor_arg(),
            bounds.into_tensor_arg(),
            into_contiguous(densities).into_tensor_arg(),
            cams.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            project_uniforms(k, &cameras, &options),
            m,
            exact,
        );
        out
    }

    fn gaussian_project_backward(
        gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
        grad: FloatTensor<Self>,
    ) -> (GaussianTensors<Self>, FloatTensor<Self>) {
        let p = Params::new(gaussians);
        let (k, m) = (p.k, p.m);
        let v = cameras.len();
        let (g, g_arg) = zero_grads(&p);
        let g_screen = zeros(&p.g.means, vec![v, k, 2]);
        let Some(first) = cameras.first() else {
            return (g, g_screen);
        };
        if k == 0 || m == 0 || first.rows == 0 || first.cols == 0 {
            return (g, g_screen);
        }
        let cams = upload(&p.g.means, pack_cameras(&cameras));
        let (count, dim) = linear(k);
        let uniforms = project_uniforms(k, &cameras, &options);
        let launch = if options.mode == ProjectionMode::Exact {
            exact::backward_exact_kernel::launch
        } else {
            project::backward_kernel::launch
        };
        launch(
            &p.g.means.client,
            count,
            dim,
            p.launch_arg(),
            into_contiguous(screen).into_tensor_arg(),
            cams.into_tensor_arg(),
            into_contiguous(prepared).into_tensor_arg(),
            into_contiguous(grad).into_tensor_arg(),
            g_arg,
            g_screen.clone().into_tensor_arg(),
            uniforms,
            m,
        );
        (g, g_screen)
    }

    fn gaussian_voxelize(
        gaussians: GaussianTensors<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
    ) -> FloatTensor<Self> {
        let p = Params::new(gaussians);
        let [nx, ny, nz] = grid.dims;
        let out = zeros(&p.g.means, vec![p.m, nz, ny, nx]);
        if p.k == 0 || p.m == 0 || grid.is_empty() {
            return out;
        }
        let grid_t = upload(&p.g.means, grid_record(&grid));
        let prepared = voxel_prepare(&p, &grid_t, &options);
        let bounds = step_bounds(&prepared, p.k, 1, VOXEL_BOXES);
        let count = CubeCount::Static(
            (nx as u32).div_ceil(voxelize::BX),
            (ny as u32).div_ceil(voxelize::BY),
            (nz as u32).div_ceil(voxelize::BZ),
        );
        voxelize::forward_kernel::launch(
            &p.g.means.client,
            count,
            CubeDim::new_3d(voxelize::BX, voxelize::BY, voxelize::BZ),
            prepared.into_tensor_arg(),
            bounds.into_tensor_arg(),
            p.g.densities.clone().into_tensor_arg(),
            grid_t.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            voxelize_uniforms(p.k, &options),
            p.m,
        );
        out
    }

    fn gaussian_voxelize_backward(
        gaussians: GaussianTensors<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
        grad: FloatTensor<Self>,
    ) -> GaussianTensors<Self> {
        let p = Params::new(gaussians);
        let (g, g_arg) = zero_grads(&p);
        if p.k == 0 || p.m == 0 || grid.is_empty() {
            return g;
        }
        let grid_t = upload(&p.g.means, grid_record(&grid));
        let prepared = voxel_prepare(&p, &grid_t, &options);
        let (count, dim) = linear(p.k);
        voxelize::backward_kernel::launch(
            &p.g.means.client,
            count,
            dim,
            p.launch_arg(),
            grid_t.into_tensor_arg(),
            prepared.into_tensor_arg(),
            into_contiguous(grad).into_tensor_arg(),
            g_arg,
            voxelize_uniforms(p.k, &options),
            p.m,
        );
        g
    }
}
