//! Host-side launch helpers of the CubeCL kernels: buffers, launch sizes, and the packed
//! cameras and grid the kernels read.

use burn_cubecl::cubecl;
use burn_cubecl::{kernel::into_contiguous, tensor::CubeTensor};
use cubecl::prelude::*;

use super::CHUNK;
use super::types::VIEW_WIDTH;
use super::voxelize::{self, GRID_WIDTH};
use crate::camera::{Camera, Projection};
use crate::options::{VoxelGrid, VoxelizeOptions};

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

/// The four Gaussian parameter tensors made contiguous.
pub struct Params {
    pub means: CubeTensor,
    pub scales: CubeTensor,
    pub rotations: CubeTensor,
    pub densities: CubeTensor,
    pub k: usize,
    pub m: usize,
}

impl Params {
    pub fn new(
        means: CubeTensor,
        scales: CubeTensor,
        rotations: CubeTensor,
        densities: CubeTensor,
    ) -> Self {
        let k = dims(&means)[0];
        let m = dims(&densities)[1];
        Self {
            means: into_contiguous(means),
            scales: into_contiguous(scales),
            rotations: into_contiguous(rotations),
            densities: into_contiguous(densities),
            k,
            m,
        }
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
    let out = zeros(&p.means, vec![p.k, voxelize::VOXEL_WIDTH]);
    let (count, dim) = linear(p.k);
    voxelize::prepare_kernel::launch(
        &p.means.client,
        count,
        dim,
        p.means.clone().into_tensor_arg(),
        p.scales.clone().into_tensor_arg(),
        p.rotations.clone().into_tensor_arg(),
        p.densities.clone().into_tensor_arg(),
        grid.clone().into_tensor_arg(),
        out.clone().into_tensor_arg(),
        p.k as u32,
        options.cutoff as f32,
        p.m,
    );
    out
}
