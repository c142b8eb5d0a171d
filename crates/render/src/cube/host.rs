//! Host-side launch helpers of the CubeCL kernels: buffers, launch sizes, and the packed
//! cameras and grid the kernels read.

use burn_cubecl::cubecl;
use burn_cubecl::{CubeBackend, kernel::into_contiguous, tensor::CubeTensor};
use cubecl::prelude::*;

use super::CHUNK;
use super::types::ProjectUniformsLaunch;
use super::types::{GaussianBuffersLaunch, VIEW_WIDTH};
use super::voxelize::{self, GRID_WIDTH, VoxelizeUniformsLaunch};
use crate::camera::{Camera, Projection};
use crate::ops::GaussianTensors;
use crate::options::{ProjectOptions, VoxelGrid, VoxelizeOptions};

/// Cameras as `[V · VIEW_WIDTH]` f32, in the order [`View::load`](super::types::View::load)
/// reads: rotation (row-major), translation, fx, fy, cx, cy, sdd, cone flag.
pub fn pack_cameras(cams: &[Camera]) -> Vec<f32> {
    let mut out = Vec::with_capacity(cams.len() * VIEW_WIDTH);
    for c in cams {
        out.extend(c.rotation.iter().flatten().map(|&v| v as f32));
        out.extend(c.translation.iter().map(|&v| v as f32));
        out.extend([c.fx, c.fy, c.cx, c.cy, c.sdd].map(|v| v as f32));
        out.push(if c.projection == Projection::Cone {
            1.0
        } else {
            0.0
        });
    }
    debug_assert_eq!(out.len(), cams.len() * VIEW_WIDTH);
    out
}

pub use prism_kernel::cube::{upload, zeros};

pub fn dims(t: &CubeTensor) -> Vec<usize> {
    t.meta.shape().to_vec()
}

/// One unit per item, [`CHUNK`]-unit cubes.
pub fn linear(n: usize) -> (CubeCount, CubeDim) {
    prism_kernel::cube::linear(n, CHUNK as u32)
}

/// The four Gaussian parameter tensors made contiguous, with their counts.
pub struct Params {
    pub g: GaussianTensors<CubeBackend>,
    /// Number of Gaussians K.
    pub k: usize,
    /// Number of density channels M.
    pub m: usize,
}

impl Params {
    pub fn new(g: GaussianTensors<CubeBackend>) -> Self {
        let k = dims(&g.means)[0];
        let m = dims(&g.densities)[1];
        let g = GaussianTensors::from_array(g.into_array().map(into_contiguous));
        Self { g, k, m }
    }

    /// The tensors as a kernel's [`GaussianBuffers`](super::types::GaussianBuffers).
    pub fn launch_arg(&self) -> GaussianBuffersLaunch {
        buffers_arg(&self.g)
    }
}

/// Four Gaussian tensors as a kernel's [`GaussianBuffers`](super::types::GaussianBuffers).
fn buffers_arg(g: &GaussianTensors<CubeBackend>) -> GaussianBuffersLaunch {
    GaussianBuffersLaunch {
        means: g.means.clone().into_tensor_arg(),
        scales: g.scales.clone().into_tensor_arg(),
        rotations: g.rotations.clone().into_tensor_arg(),
        densities: g.densities.clone().into_tensor_arg(),
    }
}

/// Zeroed gradient tensors shaped like `p`'s, launched as a kernel's gradient
/// [`GaussianBuffers`](super::types::GaussianBuffers).
pub fn zero_grads(p: &Params) -> (GaussianTensors<CubeBackend>, GaussianBuffersLaunch) {
    let like = &p.g.means;
    let g = GaussianTensors {
        means: zeros(like, vec![p.k, 3]),
        scales: zeros(like, vec![p.k, 3]),
        rotations: zeros(like, vec![p.k, 4]),
        densities: zeros(like, vec![p.k, p.m]),
    };
    let arg = buffers_arg(&g);
    (g, arg)
}

/// The [`ProjectUniforms`](super::types::ProjectUniforms) of one call with `k` Gaussians (the
/// detector size is the first camera's; 0 without cameras).
pub fn project_uniforms(
    k: usize,
    cameras: &[Camera],
    options: &ProjectOptions,
) -> ProjectUniformsLaunch {
    let (rows, cols) = cameras.first().map_or((0, 0), |c| (c.rows, c.cols));
    ProjectUniformsLaunch {
        k: k as u32,
        n_views: cameras.len() as u32,
        rows: rows as u32,
        cols: cols as u32,
        cutoff: options.cutoff as f32,
        cut2: (options.cutoff * options.cutoff) as f32,
        near_fraction: options.near_fraction as f32,
    }
}

/// The [`VoxelizeUniforms`](super::voxelize::VoxelizeUniforms) of one call with `k` Gaussians.
pub fn voxelize_uniforms(k: usize, options: &VoxelizeOptions) -> VoxelizeUniformsLaunch {
    VoxelizeUniformsLaunch {
        k: k as u32,
        cutoff: options.cutoff as f32,
        cut2: (options.cutoff * options.cutoff) as f32,
    }
}

/// A grid as the [`GRID_WIDTH`] floats [`Grid::load`](super::voxelize::Grid::load) reads:
/// counts, voxel sizes, centre offset.
pub fn grid_record(grid: &VoxelGrid) -> Vec<f32> {
    let mut v: Vec<f32> = grid.dims.iter().map(|&n| n as f32).collect();
    v.extend(grid.voxel.iter().map(|&x| x as f32));
    v.extend(grid.offset.iter().map(|&x| x as f32));
    debug_assert_eq!(v.len(), GRID_WIDTH);
    v
}

pub fn voxel_prepare(p: &Params, grid: &CubeTensor, options: &VoxelizeOptions) -> CubeTensor {
    let out = zeros(&p.g.means, vec![p.k, voxelize::VOXEL_WIDTH]);
    let (count, dim) = linear(p.k);
    voxelize::prepare_kernel::launch(
        &p.g.means.client,
        count,
        dim,
        p.launch_arg(),
        grid.clone().into_tensor_arg(),
        out.clone().into_tensor_arg(),
        voxelize_uniforms(p.k, options),
        p.m,
    );
    out
}
