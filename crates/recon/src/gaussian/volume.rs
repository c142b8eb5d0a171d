//! Gaussians voxelized on the reconstruction grid: the volumes a Gaussian run writes and scores.

use super::model::{GaussianModel, softplus};
use super::world::World;
use crate::Result;
use burn::tensor::Tensor;
use ndarray::Array4;
use prism_domain::geometry::VolumeGrid;
use prism_render::{Gaussians, VoxelizeOptions, voxelize};

/// Voxelize `model` on `grid` (millimetres): `[M][z][y][x]` densities in mm⁻¹.
pub fn volumes(model: &GaussianModel, grid: &VolumeGrid, world: &World) -> Result<Array4<f32>> {
    voxelize_gaussians(model.activate(None).gaussians, grid, world)
}

/// [`volumes`] with the model's densities replaced by raw columns `raw` `[K, M]`.
pub fn volumes_with(
    model: &GaussianModel,
    raw: Tensor<2>,
    grid: &VolumeGrid,
    world: &World,
) -> Result<Array4<f32>> {
    let mut g = model.activate(None).gaussians;
    g.densities = softplus(raw);
    voxelize_gaussians(g, grid, world)
}

fn voxelize_gaussians(g: Gaussians, grid: &VolumeGrid, world: &World) -> Result<Array4<f32>> {
    let v = voxelize(&g, &world.voxel_grid(grid), &VoxelizeOptions::default())?;
    let [m, z, y, x] = v.dims();
    let data = super::host_values(&v);
    let scale = world.density_scale as f32;
    Ok(Array4::from_shape_vec((m, z, y, x), data)
        .expect("shape of the voxelized volume")
        .mapv(|v| v * scale))
}
