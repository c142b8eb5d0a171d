//! Gaussians voxelized on the reconstruction grid and rendered at a geometry's views: the
//! volumes a Gaussian run writes and scores, and the projections it is scored on.

use super::model::{GaussianModel, softplus};
use super::world::World;
use crate::Result;
use burn::tensor::Tensor;
use ndarray::{Array3, Array4, Axis};
use prism_domain::geometry::{Geometry, VolumeGrid};
use prism_render::{Gaussians, ProjectOptions, VoxelizeOptions, project, voxelize};

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
    let data = crate::device::host_values(&v);
    let scale = world.density_scale as f32;
    Ok(Array4::from_shape_vec((m, z, y, x), data)
        .expect("shape of the voxelized volume")
        .mapv(|v| v * scale))
}

/// Render `views` of `geometry` for one density column `raw` `[K, 1]` with `options`: line
/// integrals `[view][row][col]`.
pub fn render_views(
    model: &GaussianModel,
    raw: Tensor<2>,
    world: &World,
    geometry: &Geometry,
    views: &[usize],
    options: &ProjectOptions,
) -> Result<Array3<f32>> {
    let g_world = world.geometry(geometry);
    let mut gaussians = model.activate(None).gaussians;
    gaussians.densities = softplus(raw);
    let (rows, cols) = (geometry.detector.rows, geometry.detector.cols);
    let mut out = Array3::<f32>::zeros((views.len(), rows, cols));
    let f = (1.0 / world.projection_factor()) as f32;
    // A few views per call keeps the [V, 1, rows, cols] buffers small.
    for (chunk_i, chunk) in views.chunks(8).enumerate() {
        let cams: Vec<_> = chunk.iter().map(|&v| g_world.camera(v)).collect();
        let img = project(&gaussians, &cams, None, options)?;
        let data = crate::device::host_values(&img);
        for (j, _) in chunk.iter().enumerate() {
            let dst = out.index_axis_mut(Axis(0), chunk_i * 8 + j);
            let src = &data[j * rows * cols..(j + 1) * rows * cols];
            for (d, s) in dst.into_iter().zip(src) {
                *d = s * f;
            }
        }
    }
    Ok(out)
}
