//! The Burn backend extension and the backend-free functions trainers call.
//!
//! Tensor layouts (all `f32`): means `[K, 3]`, scales `[K, 3]` (standard deviations, length units,
//! positive), rotations `[K, 4]` (quaternions `w, x, y, z`, normalised inside the op: the gradient
//! is with respect to the raw value), densities `[K, M]` (M channels sharing the geometry, e.g. the
//! energy channels of a spectral scan), screen offsets `[V, K, 2]` (pixels, see [`screen_probe`]).
//! Outputs: projections `[V, M, rows, cols]` (line integrals), volumes `[M, nz, ny, nx]`.
//! Cameras, grids and options are plain host values passed to the op as ordinary arguments.

// The NdArray selector names burn-ndarray, deprecated in Burn 0.22 (Flex is its successor).
#![allow(deprecated)]

use burn::backend::{Backend, Dispatch, backend_extension, tensor::FloatTensor};
use burn::tensor::{DType, Tensor};

use crate::camera::Camera;
use crate::error::{RenderError, Result};
use crate::options::{ProjectOptions, VoxelGrid, VoxelizeOptions};

pub use tensors::GaussianTensors;

/// [`GaussianTensors`] in a module of its own: the `ExtensionType` derive's Fusion code names
/// `Result` unqualified, which must be the standard one (this module's is [`crate::Result`]).
mod tensors {
    use burn::backend::{Backend, ExtensionType, tensor::FloatTensor};

    /// The Gaussian parameters of one op call as backend tensors (layouts in [`crate::ops`]):
    /// what every op of [`super::GaussianOps`] takes, and what the backward ops return as the
    /// parameters' gradients (same shapes).
    #[derive(ExtensionType)]
    #[extension_type(fusion: cfg(feature = "fusion"))]
    pub struct GaussianTensors<B: Backend> {
        /// Centres `[K, 3]` (world length units).
        pub means: FloatTensor<B>,
        /// Standard deviations `[K, 3]` along the rotated axes (length units, positive).
        pub scales: FloatTensor<B>,
        /// Quaternions `[K, 4]` (`w, x, y, z`, raw: the ops normalise them).
        pub rotations: FloatTensor<B>,
        /// Densities `[K, M]`, one column per channel sharing the geometry.
        pub densities: FloatTensor<B>,
    }

    impl<B: Backend> GaussianTensors<B> {
        /// The four tensors in field order (means, scales, rotations, densities).
        pub fn into_array(self) -> [FloatTensor<B>; 4] {
            [self.means, self.scales, self.rotations, self.densities]
        }

        /// The inverse of [`GaussianTensors::into_array`].
        pub fn from_array([means, scales, rotations, densities]: [FloatTensor<B>; 4]) -> Self {
            Self {
                means,
                scales,
                rotations,
                densities,
            }
        }
    }
}

/// Differentiable Gaussian projection and voxelization. Backward kernels are ops of their own so
/// every backend (CPU: [`crate::cpu`]; wgpu: `crate::cube`) provides them next to the forward.
///
/// Projection runs in two stages: [`GaussianOps::gaussian_project_prepare`] computes the
/// per-view, per-Gaussian screen-space state once (an opaque, non-differentiable f32 tensor in
/// a layout the backend chooses), and the forward and backward ops read it, so a forward and its
/// backward prepare every Gaussian once (the autodiff layer keeps the tensor for the backward).
/// The prepared tensor must come from the same inputs, cameras and options.
#[backend_extension(
    NdArray: cfg(feature = "ndarray"),
    Flex: cfg(feature = "flex"),
    Cube: cfg(feature = "wgpu"),
    Fusion: cfg(feature = "fusion"),
    Autodiff
)]
pub trait GaussianOps: Backend {
    /// The prepared state of every view and Gaussian for [`GaussianOps::gaussian_project`] and
    /// [`GaussianOps::gaussian_project_backward`] (CPU backends: `[V, K, cpu::PREPARED_WIDTH]`,
    /// see [`crate::cpu::project_prepare`]). Not differentiable.
    #[fusion(
        dtype = gaussians.means.dtype,
        shape = fusion_shapes::prepared(&gaussians.means.shape, cameras, options)
    )]
    fn gaussian_project_prepare(
        #[extension_type] gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self>;

    /// Line-integral images `[V, M, rows, cols]` of the Gaussians in every camera.
    #[fusion(
        dtype = gaussians.means.dtype,
        shape = fusion_shapes::images(&gaussians.densities.shape, cameras)
    )]
    fn gaussian_project(
        #[extension_type] gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self>;

    /// Gradients of `⟨grad, project(..)⟩` with respect to the Gaussians and the screen offsets.
    #[fusion(meta = |gaussians, screen, _prepared, _cameras, _options, _grad| (
        gaussians.clone(),
        screen.clone(),
    ))]
    fn gaussian_project_backward(
        #[extension_type] gaussians: GaussianTensors<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
        grad: FloatTensor<Self>,
    ) -> (GaussianTensors<Self>, FloatTensor<Self>);

    /// Density volumes `[M, nz, ny, nx]` on `grid`.
    #[fusion(
        dtype = gaussians.means.dtype,
        shape = fusion_shapes::volumes(&gaussians.densities.shape, grid)
    )]
    fn gaussian_voxelize(
        #[extension_type] gaussians: GaussianTensors<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
    ) -> FloatTensor<Self>;

    /// Gradients of `⟨grad, voxelize(..)⟩` with respect to the Gaussians.
    #[fusion(meta = |gaussians, _grid, _options, _grad| gaussians.clone())]
    fn gaussian_voxelize_backward(
        #[extension_type] gaussians: GaussianTensors<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
        grad: FloatTensor<Self>,
    ) -> GaussianTensors<Self>;
}

/// Output shapes of the ops, known from the inputs' shapes and the host arguments (Burn's
/// `Fusion` backend queues the ops lazily and needs them before they run).
mod fusion_shapes {
    use super::*;
    use burn::tensor::Shape;

    /// `[V, K, width]` of the prepared records of the backend `Fusion` wraps (the Cube
    /// backend: feature `fusion` implies `wgpu`).
    #[allow(dead_code)]
    pub fn prepared(means: &Shape, cameras: &[Camera], options: &ProjectOptions) -> Shape {
        #[cfg(feature = "wgpu")]
        let width = crate::cube::layout::prepared_width(options.mode);
        #[cfg(not(feature = "wgpu"))]
        let width = crate::cpu::prepared_width(options.mode);
        Shape::from(vec![cameras.len(), means[0], width])
    }

    /// `[V, M, rows, cols]`.
    #[allow(dead_code)]
    pub fn images(densities: &Shape, cameras: &[Camera]) -> Shape {
        let (rows, cols) = cameras.first().map_or((0, 0), |c| (c.rows, c.cols));
        Shape::from(vec![cameras.len(), densities[1], rows, cols])
    }

    /// `[M, nz, ny, nx]`.
    #[allow(dead_code)]
    pub fn volumes(densities: &Shape, grid: &VoxelGrid) -> Shape {
        let [nx, ny, nz] = grid.dims;
        Shape::from(vec![densities[1], nz, ny, nx])
    }
}

/// The Gaussian parameters as Burn tensors (see the module docs for layouts).
#[derive(Clone, Debug)]
pub struct Gaussians {
    pub means: Tensor<2>,
    pub scales: Tensor<2>,
    pub rotations: Tensor<2>,
    pub densities: Tensor<2>,
}

impl Gaussians {
    /// The four tensors as the ops' [`GaussianTensors`].
    fn into_dispatch(self) -> GaussianTensors<Dispatch> {
        GaussianTensors {
            means: self.means.into_dispatch(),
            scales: self.scales.into_dispatch(),
            rotations: self.rotations.into_dispatch(),
            densities: self.densities.into_dispatch(),
        }
    }

    /// Number of Gaussians K.
    pub fn len(&self) -> usize {
        self.means.dims()[0]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of density channels M.
    pub fn channels(&self) -> usize {
        self.densities.dims()[1]
    }

    /// Check shapes and dtypes; returns `(K, M)`.
    pub fn validate(&self) -> Result<(usize, usize)> {
        let k = self.means.dims()[0];
        let check = |name: &str, t: &Tensor<2>, cols: Option<usize>| -> Result<()> {
            let [rows, c] = t.dims();
            if rows != k {
                return Err(RenderError::invalid(
                    name,
                    format!("has {rows} rows, means has {k}"),
                ));
            }
            if let Some(want) = cols
                && c != want
            {
                return Err(RenderError::invalid(
                    name,
                    format!("must be [K, {want}], got [{rows}, {c}]"),
                ));
            }
            if t.dtype() != DType::F32 {
                return Err(RenderError::invalid(
                    name,
                    format!("must be f32, got {:?}", t.dtype()),
                ));
            }
            Ok(())
        };
        check("means", &self.means, Some(3))?;
        check("scales", &self.scales, Some(3))?;
        check("rotations", &self.rotations, Some(4))?;
        check("densities", &self.densities, None)?;
        let m = self.densities.dims()[1];
        if m == 0 {
            return Err(RenderError::invalid(
                "densities",
                "needs at least one channel column",
            ));
        }
        Ok((k, m))
    }
}

/// Check the cameras of one call: at least one, all finite, one detector size.
pub fn validate_cameras(cameras: &[Camera]) -> Result<()> {
    let Some(first) = cameras.first() else {
        return Err(RenderError::invalid(
            "cameras",
            "at least one view is needed",
        ));
    };
    for (i, c) in cameras.iter().enumerate() {
        let field = |f: &str| format!("cameras[{i}].{f}");
        if c.rows > 1 << 20 || c.cols > 1 << 20 {
            return Err(RenderError::invalid(
                field("rows/cols"),
                format!(
                    "{}×{} exceeds the 2^20 pixel limit per axis",
                    c.rows, c.cols
                ),
            ));
        }
        if c.rows == 0 || c.cols == 0 {
            return Err(RenderError::invalid(
                field("rows/cols"),
                "detector must have at least one pixel",
            ));
        }
        if (c.rows, c.cols) != (first.rows, first.cols) {
            return Err(RenderError::invalid(
                field("rows/cols"),
                format!(
                    "{}×{} differs from view 0's {}×{}",
                    c.rows, c.cols, first.rows, first.cols
                ),
            ));
        }
        for (name, v) in [("fx", c.fx), ("fy", c.fy), ("sdd", c.sdd)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(RenderError::invalid(
                    field(name),
                    format!("must be finite and > 0, got {v}"),
                ));
            }
        }
        if !(c.cx.is_finite() && c.cy.is_finite()) {
            return Err(RenderError::invalid(field("cx/cy"), "must be finite"));
        }
        if !c
            .rotation
            .iter()
            .flatten()
            .chain(&c.translation)
            .all(|v| v.is_finite())
        {
            return Err(RenderError::invalid(
                field("rotation/translation"),
                "must be finite",
            ));
        }
    }
    Ok(())
}

/// Project Gaussians into every camera: `[V, M, rows, cols]` line integrals.
///
/// `screen` is an optional `[V, K, 2]` tensor of offsets (pixels) added to the projected centres;
/// pass a [`screen_probe`] to read the densification statistic after `backward`. Differentiable
/// with respect to every tensor input through ordinary Burn autodiff.
pub fn project(
    gaussians: &Gaussians,
    cameras: &[Camera],
    screen: Option<&Tensor<3>>,
    options: &ProjectOptions,
) -> Result<Tensor<4>> {
    let (k, _) = gaussians.validate()?;
    validate_cameras(cameras)?;
    options.validate()?;
    let v = cameras.len();
    let screen = match screen {
        Some(s) => {
            if s.dims() != [v, k, 2] {
                return Err(RenderError::invalid(
                    "screen",
                    format!("must be [{v}, {k}, 2], got {:?}", s.dims()),
                ));
            }
            if s.dtype() != DType::F32 {
                return Err(RenderError::invalid("screen", "must be f32"));
            }
            s.clone()
        }
        None => Tensor::<3>::zeros([v, k, 2], &gaussians.means.device()),
    };
    let prepared = Dispatch::gaussian_project_prepare(
        gaussians.clone().into_dispatch(),
        screen.clone().into_dispatch(),
        cameras.to_vec(),
        *options,
    );
    Ok(Tensor::from_dispatch(Dispatch::gaussian_project(
        gaussians.clone().into_dispatch(),
        screen.into_dispatch(),
        prepared,
        cameras.to_vec(),
        *options,
    )))
}

/// Whether tensors on `device` run on the CubeCL (wgpu) backend rather than a CPU one.
pub fn is_gpu(device: &burn::tensor::Device) -> bool {
    #[cfg(feature = "wgpu")]
    {
        matches!(
            device.clone().inner().as_dispatch(),
            burn::backend::DispatchDevice::Cube(_)
        )
    }
    #[cfg(not(feature = "wgpu"))]
    {
        let _ = device;
        false
    }
}

/// Evaluate the Gaussians' density at the voxel centres of `grid`: `[M, nz, ny, nx]`.
pub fn voxelize(
    gaussians: &Gaussians,
    grid: &VoxelGrid,
    options: &VoxelizeOptions,
) -> Result<Tensor<4>> {
    gaussians.validate()?;
    grid.validate()?;
    options.validate()?;
    Ok(Tensor::from_dispatch(Dispatch::gaussian_voxelize(
        gaussians.clone().into_dispatch(),
        *grid,
        *options,
    )))
}

/// A zero `[views, K, 2]` screen-offset tensor that requires grad: pass it to [`project`], and
/// after `backward` its gradient is `∂L/∂(projected centre)` per view and Gaussian in pixels.
pub fn screen_probe(gaussians: &Gaussians, views: usize) -> Tensor<3> {
    Tensor::<3>::zeros([views, gaussians.len(), 2], &gaussians.means.device()).require_grad()
}

/// The densification statistic: `Σ_views ‖∂L/∂(projected centre)‖₂` per Gaussian (pixels⁻¹),
/// from a [`screen_probe`]'s gradient `[V, K, 2]`. (Upstream 3DGS measures it in NDC units, i.e.
/// this value times half the detector size in pixels.)
pub fn screen_grad_norm(grad: &Tensor<3>) -> Tensor<1> {
    let [_, k, _] = grad.dims();
    (grad.clone() * grad.clone())
        .sum_dim(2)
        .sqrt()
        .sum_dim(0)
        .reshape([k])
}

#[cfg(test)]
pub(crate) mod tests;
