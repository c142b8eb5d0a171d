//! Initial Gaussians from an FDK reconstruction of the training views (R²-Gaussian §4).
//!
//! Voxels whose normalised FDK value exceeds `threshold` are candidates; `n_points` of them are
//! drawn without replacement (seeded). Each becomes an isotropic Gaussian at the voxel centre with
//! scale `√(mean squared distance to its 3 nearest neighbours)` (a k-d tree, `kiddo`), clamped
//! into the scale bounds, and density `rescale × FDK value`. `rescale` is either upstream's fixed
//! 0.15 or fitted: the least-squares factor that makes the voxelized initial Gaussians match the
//! FDK volume (one voxelization; the voxelization is linear in the densities).

use crate::algorithms::{Window, fdk};
use crate::gaussians::config::{DensityRescale, InitConfig, RescaleRule};
use crate::gaussians::host::{HostGaussians, ScaleBounds, inverse_softplus};
use crate::gaussians::{GaussianModel, GeometryConfig, World};
use crate::{Error, Result};
use burn::tensor::Device;
use kiddo::SquaredEuclidean;
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use ndarray::ArrayView3;
use ndarray::{Array3, Axis};
use prism_domain::geometry::{Geometry, VolumeGrid};
use rand::SeedableRng;
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;
use std::num::NonZero;

/// The density scale (mm⁻¹) of a volume: its 99.9th percentile of positive values, so that a
/// few streak voxels of a sparse-view FDK do not set the unit.
pub fn density_scale(volume: ArrayView3<f32>) -> Result<f64> {
    let mut pos: Vec<f32> = volume
        .iter()
        .copied()
        .filter(|v| *v > 0.0 && v.is_finite())
        .collect();
    if pos.is_empty() {
        return Err(Error::invalid(
            "init",
            "the FDK reconstruction has no positive value (empty projections?)",
        ));
    }
    let i = ((pos.len() - 1) as f64 * 0.999).round() as usize;
    let (_, v, _) = pos.select_nth_unstable_by(i, |a, b| a.total_cmp(b));
    Ok(*v as f64)
}

/// Gaussians (one density column, raw values) from `fdk` (mm⁻¹, `[z][y][x]` on `grid`).
pub fn from_fdk(
    fdk: ArrayView3<f32>,
    grid: &VolumeGrid,
    world: &World,
    bounds: &ScaleBounds,
    config: &InitConfig,
    seed: u64,
    device: &Device,
) -> Result<HostGaussians> {
    config.validate()?;
    let ng = world.volume(grid);
    let [nz, ny, nx] = grid.shape_zyx();
    prism_domain::error::ensure_shape("fdk", fdk.shape(), &[nz, ny, nx], "[z, y, x] of the grid")?;
    let candidates: Vec<(usize, f32)> = fdk
        .iter()
        .enumerate()
        .filter_map(|(i, &v)| {
            let n = (v as f64 / world.density_scale) as f32;
            (n > config.threshold as f32).then_some((i, n))
        })
        .collect();
    if candidates.is_empty() {
        return Err(Error::invalid(
            "init.threshold",
            format!(
                "no FDK voxel exceeds {} (normalised); lower the threshold",
                config.threshold
            ),
        ));
    }
    let n = config.n_points.min(candidates.len());
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut picked: Vec<usize> = sample(&mut rng, candidates.len(), n).into_vec();
    picked.sort_unstable();
    let points: Vec<[f32; 3]> = picked
        .iter()
        .map(|&j| {
            let i = candidates[j].0;
            let c = ng.voxel_centre(i % nx, (i / nx) % ny, i / (nx * ny));
            [c[0] as f32, c[1] as f32, c[2] as f32]
        })
        .collect();
    let scales = neighbour_scales(&points, config.neighbours, bounds);
    let mut host = HostGaussians::empty(1);
    for (p, s) in points.iter().zip(&scales) {
        host.means.extend_from_slice(p);
        let raw = bounds.raw(*s) as f32;
        host.scales.extend_from_slice(&[raw, raw, raw]);
        host.rotations.extend_from_slice(&[1.0, 0.0, 0.0, 0.0]);
    }
    let values: Vec<f64> = picked.iter().map(|&j| candidates[j].1 as f64).collect();
    let rescale = match config.density_rescale {
        DensityRescale::Factor(f) => f,
        DensityRescale::Named(RescaleRule::Fit) => {
            fit_rescale(&host, &values, fdk, grid, world, bounds, device)?
        }
    };
    host.densities = values
        .iter()
        .map(|v| inverse_softplus(v * rescale) as f32)
        .collect();
    host.validate()?;
    Ok(host)
}

/// `√(mean squared distance to the k nearest other points)`, floored at 0.001 and clamped 1e-5
/// inside the bounds (R²-Gaussian's rule).
fn neighbour_scales(points: &[[f32; 3]], k: usize, bounds: &ScaleBounds) -> Vec<f64> {
    let lo = bounds.min + 1e-5;
    let hi = bounds.max - 1e-5;
    if points.len() < 2 {
        return vec![hi.min(0.1).max(lo); points.len()];
    }
    let tree: ImmutableKdTree<f32, u32, 3, 32> = ImmutableKdTree::new_from_slice(points);
    let want = NonZero::new((k + 1).min(points.len())).expect("at least one");
    points
        .iter()
        .map(|p| {
            let nn = tree.nearest_n::<SquaredEuclidean>(p, want);
            // The query point itself is among the results at distance 0; drop one zero.
            let mut d: Vec<f64> = nn.iter().map(|n| n.distance as f64).collect();
            d.sort_by(|a, b| a.total_cmp(b));
            let others = &d[1..];
            let mean = others.iter().sum::<f64>() / others.len() as f64;
            mean.sqrt().max(0.001).clamp(lo, hi)
        })
        .collect()
}

/// Least-squares factor `a` minimising `‖a·V(ρ = values) − FDK‖²` over the grid (normalised units).
fn fit_rescale(
    host: &HostGaussians,
    values: &[f64],
    fdk: ArrayView3<f32>,
    grid: &VolumeGrid,
    world: &World,
    bounds: &ScaleBounds,
    device: &Device,
) -> Result<f64> {
    let mut probe = host.clone();
    probe.densities = values.iter().map(|&v| inverse_softplus(v) as f32).collect();
    let model = crate::gaussians::GaussianModel::new(&probe, *bounds, device);
    let g = model.activate(None).gaussians;
    let vol = prism_render::voxelize(&g, &world.voxel_grid(grid), &Default::default())
        .map_err(|e| Error::invalid("init", e.to_string()))?;
    let v = crate::device::host_values(&vol);
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (a, b) in v.iter().zip(fdk.iter()) {
        let b = *b as f64 / world.density_scale;
        num += *a as f64 * b;
        den += (*a as f64).powi(2);
    }
    if !(den > 0.0 && num > 0.0) {
        return Err(Error::invalid(
            "init.density_rescale",
            "the fitted factor is not positive; use a fixed factor",
        ));
    }
    Ok(num / den)
}

/// FDK (ram-lak) of `projections` (`[view][row][col]` for the listed views of `geometry`).
pub fn fdk_of(
    geometry: &Geometry,
    projections: ndarray::ArrayView3<f32>,
    views: &[usize],
) -> Result<Array3<f32>> {
    fdk(
        &geometry.with_views(views),
        projections.select(Axis(0), views).view(),
        Window::RamLak,
    )
}

/// The initial model and its world from an FDK of `projections` at `views`.
pub fn initial_model(
    config: &GeometryConfig,
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    views: &[usize],
    device: &Device,
) -> Result<(GaussianModel, World)> {
    let init_fdk = fdk_of(geometry, projections, views)?;
    let world = World::new(geometry, density_scale(init_fdk.view())?)?;
    let bounds = config.bounds();
    let host = from_fdk(
        init_fdk.view(),
        &geometry.volume,
        &world,
        &bounds,
        &config.init,
        config.seed,
        device,
    )?;
    Ok((GaussianModel::new(&host, bounds, device), world))
}
