//! The Burn backend extension of the hash-grid encoder and the function models call.
//!
//! Layouts (`f32`): points `[N, 3]` in the unit cube, the table `[rows, F]`, encodings
//! `[N, L·F]` ([`crate::grid`] has the indexing). The encoder is differentiable with respect to
//! the table (a scatter-add of the output gradient into the corners' rows), not the points.

// The NdArray selector names burn-ndarray, deprecated in Burn 0.22 (Flex is its successor).
#![allow(deprecated)]

use burn::backend::{Backend, Dispatch, backend_extension, tensor::FloatTensor};
use burn::tensor::{DType, Tensor};

use crate::error::{FieldError, Result};
use crate::grid::HashGrid;
use crate::mlp::MlpLayout;

/// The hash-grid encoder as a backend op (CPU: [`crate::cpu`]; wgpu: `crate::cube`), with its
/// backward as an op of its own.
#[backend_extension(
    NdArray: cfg(feature = "ndarray"),
    Flex: cfg(feature = "flex"),
    Cube: cfg(feature = "wgpu"),
    Fusion: cfg(feature = "fusion"),
    Autodiff
)]
pub trait FieldOps: Backend {
    /// Encodings `[N, L·F]` of `points` `[N, 3]` with `table` `[rows, F]`.
    #[fusion(dtype = points, shape = fusion_shapes::encoding(points, grid))]
    fn hash_grid_encode(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self>;

    /// The table's gradient `[rows, F]` of `⟨grad, hash_grid_encode(points, ·)⟩`.
    #[fusion(dtype = points, shape = fusion_shapes::table(grid))]
    fn hash_grid_encode_backward(
        points: FloatTensor<Self>,
        grid: HashGrid,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The MLP's outputs `[N, 1]` at encodings `enc` `[N, input]` with the packed `params`
    /// ([`crate::mlp`]).
    #[fusion(dtype = enc, shape = fusion_shapes::mlp(enc))]
    fn field_mlp(
        enc: FloatTensor<Self>,
        params: FloatTensor<Self>,
        layout: MlpLayout,
    ) -> FloatTensor<Self>;

    /// The gradients of `⟨grad, field_mlp(enc, params)⟩` with respect to `enc` and `params`.
    #[fusion(meta = |enc, params, _layout, _grad| (enc.clone(), params.clone()))]
    fn field_mlp_backward(
        enc: FloatTensor<Self>,
        params: FloatTensor<Self>,
        layout: MlpLayout,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

/// Output shapes from input shapes (Burn's `Fusion` queues ops before they run).
mod fusion_shapes {
    use super::HashGrid;
    use burn::tensor::Shape;

    #[allow(dead_code)]
    pub fn encoding(points: &Shape, grid: &HashGrid) -> Shape {
        Shape::from(vec![points[0], grid.width()])
    }

    #[allow(dead_code)]
    pub fn table(grid: &HashGrid) -> Shape {
        Shape::from(vec![grid.rows(), grid.features])
    }

    #[allow(dead_code)]
    pub fn mlp(enc: &Shape) -> Shape {
        Shape::from(vec![enc[0], 1])
    }
}

/// Encode `points` `[N, 3]` (unit cube) with `table` `[grid.rows(), F]`: `[N, L·F]`.
/// Differentiable with respect to `table`.
pub fn encode(points: Tensor<2>, table: Tensor<2>, grid: &HashGrid) -> Result<Tensor<2>> {
    let [_, d] = points.dims();
    if d != 3 {
        return Err(FieldError::invalid(
            "points",
            format!("must be [N, 3], got {:?}", points.dims()),
        ));
    }
    let want = [grid.rows(), grid.features];
    if table.dims() != want {
        return Err(FieldError::invalid(
            "table",
            format!("must be {want:?} for this grid, got {:?}", table.dims()),
        ));
    }
    for (name, t) in [("points", &points), ("table", &table)] {
        if t.dtype() != DType::F32 {
            return Err(FieldError::invalid(
                name,
                format!("must be f32, got {:?}", t.dtype()),
            ));
        }
    }
    Ok(Tensor::from_dispatch(Dispatch::hash_grid_encode(
        points.into_dispatch(),
        table.into_dispatch(),
        grid.clone(),
    )))
}

/// The MLP of [`crate::mlp`] at encodings `enc` `[N, layout.input]` with the packed `params`
/// `[layout.params()]`: `[N, 1]`. Differentiable with respect to both.
pub fn mlp(enc: Tensor<2>, params: Tensor<1>, layout: MlpLayout) -> Result<Tensor<2>> {
    if enc.dims()[1] != layout.input {
        return Err(FieldError::invalid(
            "enc",
            format!("must be [N, {}], got {:?}", layout.input, enc.dims()),
        ));
    }
    if params.dims()[0] != layout.params() {
        return Err(FieldError::invalid(
            "params",
            format!(
                "must hold {} values, got {}",
                layout.params(),
                params.dims()[0]
            ),
        ));
    }
    Ok(Tensor::from_dispatch(Dispatch::field_mlp(
        enc.into_dispatch(),
        params.into_dispatch(),
        layout,
    )))
}
