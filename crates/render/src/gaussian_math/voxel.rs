//! A Gaussian's value at voxel centres (voxelization) and its backward pass.

use super::*;

/// A Gaussian prepared for voxelization: value at `x` is `ρ · exp(−½ q(x − mean))`.
#[derive(Clone, Copy, Debug)]
pub struct VoxelSplat {
    pub mean: V3,
    pub quad: Quad3,
    /// Half-extent of the cut-off ellipsoid's bounding box per world axis: `cutoff · √Σ_ii`.
    pub half_extent: V3,
}

pub fn voxel_splat(g: &GaussianGeom, cutoff: f64) -> Option<VoxelSplat> {
    let shape = shape3(g)?;
    let quad = Quad3::new(&shape.prec)?;
    let half_extent = [
        cutoff * shape.cov[0][0].sqrt(),
        cutoff * shape.cov[1][1].sqrt(),
        cutoff * shape.cov[2][2].sqrt(),
    ];
    half_extent
        .iter()
        .all(|v| v.is_finite())
        .then_some(VoxelSplat {
            mean: g.mean,
            quad,
            half_extent,
        })
}

/// Backward of the voxel value given the accumulated moments of `w = ∂L/∂value · ρ`-weighted
/// unit Gaussians: `sum_d = Σ w G d`, `sum_dd = Σ w G d dᵀ` (d = voxel centre − mean).
/// Returns the geometry gradient (mean, scale, quaternion).
pub fn voxel_backward(g: &GaussianGeom, sum_d: V3, sum_dd: &M3) -> GeomGrad {
    let Some(shape) = shape3(g) else {
        return GeomGrad::default();
    };
    // ∂G/∂mean = G · P d;  ∂G/∂P = −½ G d dᵀ.
    let g_mean = mat_vec(&shape.prec, sum_d);
    let mut g_prec = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            g_prec[i][j] = -0.5 * sum_dd[i][j];
        }
    }
    let (g_scale, g_quat) = shape3_backward(&shape, &[[0.0; 3]; 3], &g_prec);
    GeomGrad {
        mean: g_mean,
        scale: g_scale,
        quat: g_quat,
    }
}
