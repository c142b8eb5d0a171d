//! CPU backends: one kernel implementation ([`crate::cpu`]) registered for every CPU backend
//! through [`CpuFloat`], which borrows the tensors' f32 buffers (no `TensorData` round trip on
//! input, no copy of the outputs).

#[cfg(any(feature = "flex", feature = "ndarray"))]
use prism_kernel::cpu::CpuFloat;

/// The Gaussian parameter buffers of a CPU backend as [`crate::cpu::GaussianSlices`], with the
/// buffers of the `extra` tensors.
#[cfg(any(feature = "flex", feature = "ndarray"))]
fn with_gaussians<B: CpuFloat, R>(
    gaussians: &crate::ops::GaussianTensors<B>,
    extra: &[&burn::backend::tensor::FloatTensor<B>],
    f: impl FnOnce(&crate::cpu::GaussianSlices, &[&[f32]]) -> R,
) -> R {
    let channels = B::dims(&gaussians.densities)[1];
    let tensors = [
        &gaussians.means,
        &gaussians.scales,
        &gaussians.rotations,
        &gaussians.densities,
    ];
    B::with_values(tensors, |[m, s, r, d]| {
        let extra: Vec<_> = extra.iter().map(|t| B::values(t)).collect();
        let extra: Vec<&[f32]> = extra.iter().map(|v| &**v).collect();
        let g = crate::cpu::GaussianSlices {
            means: m,
            scales: s,
            rotations: r,
            densities: d,
            channels,
        };
        f(&g, &extra)
    })
}

/// Implements [`crate::GaussianOps`] for a CPU backend (one that implements [`CpuFloat`]).
macro_rules! impl_cpu_gaussian_ops {
    ($backend:ty) => {
        impl $crate::ops::GaussianOps for $backend {
            fn gaussian_project_prepare(
                gaussians: $crate::ops::GaussianTensors<Self>,
                screen: FloatTensor<Self>,
                cameras: Vec<$crate::Camera>,
                options: $crate::ProjectOptions,
            ) -> FloatTensor<Self> {
                let k = Self::dims(&gaussians.means)[0];
                let out = with_gaussians::<Self, _>(&gaussians, &[&screen], |g, x| {
                    $crate::cpu::project_prepare(g, x[0], &cameras, &options)
                });
                Self::tensor(
                    out,
                    vec![cameras.len(), k, $crate::cpu::prepared_width(options.mode)],
                )
            }

            fn gaussian_project(
                gaussians: $crate::ops::GaussianTensors<Self>,
                screen: FloatTensor<Self>,
                prepared: FloatTensor<Self>,
                cameras: Vec<$crate::Camera>,
                options: $crate::ProjectOptions,
            ) -> FloatTensor<Self> {
                let channels = Self::dims(&gaussians.densities)[1];
                let out = with_gaussians::<Self, _>(&gaussians, &[&screen, &prepared], |g, x| {
                    $crate::cpu::project_forward_prepared(g, x[0], x[1], &cameras, &options)
                });
                let (rows, cols) = cameras.first().map_or((0, 0), |c| (c.rows, c.cols));
                Self::tensor(out, vec![cameras.len(), channels, rows, cols])
            }

            fn gaussian_project_backward(
                gaussians: $crate::ops::GaussianTensors<Self>,
                screen: FloatTensor<Self>,
                prepared: FloatTensor<Self>,
                cameras: Vec<$crate::Camera>,
                options: $crate::ProjectOptions,
                grad: FloatTensor<Self>,
            ) -> ($crate::ops::GaussianTensors<Self>, FloatTensor<Self>) {
                let k = Self::dims(&gaussians.means)[0];
                let channels = Self::dims(&gaussians.densities)[1];
                let g =
                    with_gaussians::<Self, _>(&gaussians, &[&screen, &prepared, &grad], |g, x| {
                        $crate::cpu::project_backward_prepared(
                            g, x[0], x[1], &cameras, &options, x[2],
                        )
                    });
                (
                    $crate::ops::GaussianTensors {
                        means: Self::tensor(g.means, vec![k, 3]),
                        scales: Self::tensor(g.scales, vec![k, 3]),
                        rotations: Self::tensor(g.rotations, vec![k, 4]),
                        densities: Self::tensor(g.densities, vec![k, channels]),
                    },
                    Self::tensor(g.screen, vec![cameras.len(), k, 2]),
                )
            }

            fn gaussian_voxelize(
                gaussians: $crate::ops::GaussianTensors<Self>,
                grid: $crate::VoxelGrid,
                options: $crate::VoxelizeOptions,
            ) -> FloatTensor<Self> {
                let channels = Self::dims(&gaussians.densities)[1];
                let out = with_gaussians::<Self, _>(&gaussians, &[], |g, _| {
                    $crate::cpu::voxelize_forward(g, &grid, &options)
                });
                let [nx, ny, nz] = grid.dims;
                Self::tensor(out, vec![channels, nz, ny, nx])
            }

            fn gaussian_voxelize_backward(
                gaussians: $crate::ops::GaussianTensors<Self>,
                grid: $crate::VoxelGrid,
                options: $crate::VoxelizeOptions,
                grad: FloatTensor<Self>,
            ) -> $crate::ops::GaussianTensors<Self> {
                let k = Self::dims(&gaussians.means)[0];
                let channels = Self::dims(&gaussians.densities)[1];
                let g = with_gaussians::<Self, _>(&gaussians, &[&grad], |g, x| {
                    $crate::cpu::voxelize_backward(g, &grid, &options, x[0])
                });
                $crate::ops::GaussianTensors {
                    means: Self::tensor(g.means, vec![k, 3]),
                    scales: Self::tensor(g.scales, vec![k, 3]),
                    rotations: Self::tensor(g.rotations, vec![k, 4]),
                    densities: Self::tensor(g.densities, vec![k, channels]),
                }
            }
        }
    };
}

#[cfg(feature = "flex")]
mod flex {
    use super::*;
    use burn::backend::{Flex, tensor::FloatTensor};
    impl_cpu_gaussian_ops!(Flex);
}

// burn-ndarray is deprecated in Burn 0.22 (Flex is its successor); kept while it exists.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
mod ndarray {
    use super::*;
    use burn::backend::{NdArray, tensor::FloatTensor};
    impl_cpu_gaussian_ops!(NdArray);
}
