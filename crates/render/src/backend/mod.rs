//! CPU backends: one kernel implementation ([`crate::cpu`]) registered for NdArray and Flex through
//! thin adapters that borrow the primitives' buffers (no `TensorData` round trip on input).

#[cfg(feature = "flex")]
mod flex;
#[cfg(feature = "ndarray")]
mod ndarray;

/// Borrow the four Gaussian parameter buffers of a CPU backend as [`crate::cpu::GaussianSlices`]
/// bound to `$g` while `$body` runs.
macro_rules! with_gaussians {
    ($read:path, $means:expr, $scales:expr, $rotations:expr, $densities:expr, $channels:expr,
     |$g:ident| $body:expr) => {
        $read($means, |means| {
            $read($scales, |scales| {
                $read($rotations, |rotations| {
                    $read($densities, |densities| {
                        let $g = $crate::cpu::GaussianSlices {
                            means,
                            scales,
                            rotations,
                            densities,
                            channels: $channels,
                        };
                        $body
                    })
                })
            })
        })
    };
}
pub(crate) use with_gaussians;

/// Implements [`crate::GaussianOps`] for a CPU backend given `read(&tensor, |&[f32]| ..)`,
/// `write(Vec<f32>, shape)` and `dims(&tensor) -> Vec<usize>`.
macro_rules! impl_cpu_gaussian_ops {
    ($backend:ty, $read:path, $write:path, $dims:path) => {
        impl $crate::ops::GaussianOps for $backend {
            fn gaussian_project_prepare(
                means: FloatTensor<Self>,
                scales: FloatTensor<Self>,
                rotations: FloatTensor<Self>,
                densities: FloatTensor<Self>,
                screen: FloatTensor<Self>,
                cameras: Vec<$crate::Camera>,
                options: $crate::ProjectOptions,
            ) -> FloatTensor<Self> {
                let k = $dims(&means)[0];
                let channels = $dims(&densities)[1];
                let out = $crate::backend::with_gaussians!(
                    $read,
                    &means,
                    &scales,
                    &rotations,
                    &densities,
                    channels,
                    |g| $read(&screen, |screen| {
                        $crate::cpu::project_prepare(&g, screen, &cameras, &options)
                    })
                );
                $write(out, vec![cameras.len(), k, $crate::cpu::PREPARED_WIDTH])
            }

            fn gaussian_project(
                means: FloatTensor<Self>,
                scales: FloatTensor<Self>,
                rotations: FloatTensor<Self>,
                densities: FloatTensor<Self>,
                screen: FloatTensor<Self>,
                prepared: FloatTensor<Self>,
                cameras: Vec<$crate::Camera>,
                options: $crate::ProjectOptions,
            ) -> FloatTensor<Self> {
                let channels = $dims(&densities)[1];
                let out = $crate::backend::with_gaussians!(
                    $read,
                    &means,
                    &scales,
                    &rotations,
                    &densities,
                    channels,
                    |g| $read(&screen, |screen| {
                        $read(&prepared, |prepared| {
                            $crate::cpu::project_forward_prepared(
                                &g, screen, prepared, &cameras, &options,
                            )
                        })
                    })
                );
                let (rows, cols) = cameras.first().map_or((0, 0), |c| (c.rows, c.cols));
                $write(out, vec![cameras.len(), channels, rows, cols])
            }

            fn gaussian_project_backward(
                means: FloatTensor<Self>,
                scales: FloatTensor<Self>,
                rotations: FloatTensor<Self>,
                densities: FloatTensor<Self>,
                screen: FloatTensor<Self>,
                prepared: FloatTensor<Self>,
                cameras: Vec<$crate::Camera>,
                options: $crate::ProjectOptions,
                grad: FloatTensor<Self>,
            ) -> (
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
            ) {
                let k = $dims(&means)[0];
                let channels = $dims(&densities)[1];
                let g = $crate::backend::with_gaussians!(
                    $read,
                    &means,
                    &scales,
                    &rotations,
                    &densities,
                    channels,
                    |g| $read(&screen, |screen| {
                        $read(&prepared, |prepared| {
                            $read(&grad, |grad| {
                                $crate::cpu::project_backward_prepared(
                                    &g, screen, prepared, &cameras, &options, grad,
                                )
                            })
                        })
                    })
                );
                (
                    $write(g.means, vec![k, 3]),
                    $write(g.scales, vec![k, 3]),
                    $write(g.rotations, vec![k, 4]),
                    $write(g.densities, vec![k, channels]),
                    $write(g.screen, vec![cameras.len(), k, 2]),
                )
            }

            fn gaussian_voxelize(
                means: FloatTensor<Self>,
                scales: FloatTensor<Self>,
                rotations: FloatTensor<Self>,
                densities: FloatTensor<Self>,
                grid: $crate::VoxelGrid,
                options: $crate::VoxelizeOptions,
            ) -> FloatTensor<Self> {
                let channels = $dims(&densities)[1];
                let out = $crate::backend::with_gaussians!(
                    $read,
                    &means,
                    &scales,
                    &rotations,
                    &densities,
                    channels,
                    |g| $crate::cpu::voxelize_forward(&g, &grid, &options)
                );
                let [nx, ny, nz] = grid.dims;
                $write(out, vec![channels, nz, ny, nx])
            }

            fn gaussian_voxelize_backward(
                means: FloatTensor<Self>,
                scales: FloatTensor<Self>,
                rotations: FloatTensor<Self>,
                densities: FloatTensor<Self>,
                grid: $crate::VoxelGrid,
                options: $crate::VoxelizeOptions,
                grad: FloatTensor<Self>,
            ) -> (
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
            ) {
                let k = $dims(&means)[0];
                let channels = $dims(&densities)[1];
                let g = $crate::backend::with_gaussians!(
                    $read,
                    &means,
                    &scales,
                    &rotations,
                    &densities,
                    channels,
                    |g| $read(&grad, |grad| {
                        $crate::cpu::voxelize_backward(&g, &grid, &options, grad)
                    })
                );
                (
                    $write(g.means, vec![k, 3]),
                    $write(g.scales, vec![k, 3]),
                    $write(g.rotations, vec![k, 4]),
                    $write(g.densities, vec![k, channels]),
                )
            }
        }
    };
}
pub(crate) use impl_cpu_gaussian_ops;
