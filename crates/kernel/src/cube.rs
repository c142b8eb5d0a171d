//! Launch helpers of the CubeCL kernels (Burn's `CubeBackend`), shared by the render and field
//! ops: zeroed and uploaded f32 buffers, 1-D launch sizes, and the f32 atomic-add capability.

use burn::backend::ops::FloatTensorOps;
use burn::tensor::{DType, Shape, TensorData};
use burn_cubecl::cubecl;
use burn_cubecl::{CubeBackend, ops::numeric::zeros_client, tensor::CubeTensor};
use cubecl::prelude::*;

/// A zeroed f32 tensor of `shape` on `like`'s device.
pub fn zeros(like: &CubeTensor, shape: Vec<usize>) -> CubeTensor {
    zeros_client(
        like.client.clone(),
        like.device.clone(),
        Shape::from(shape),
        DType::F32,
    )
}

/// `values` as a 1-D f32 tensor on `like`'s device.
pub fn upload(like: &CubeTensor, values: Vec<f32>) -> CubeTensor {
    let n = values.len();
    CubeBackend::float_from_data(TensorData::new(values, [n]), &like.device)
}

/// One unit per item, `cube` units per cube (at least one cube).
pub fn linear(n: usize, cube: u32) -> (CubeCount, CubeDim) {
    let n = u32::try_from(n).expect("kernel item count fits in u32");
    (
        CubeCount::Static(n.div_ceil(cube).max(1), 1, 1),
        CubeDim::new_1d(cube),
    )
}

/// Whether `t`'s device adds f32 atomically (`Atomic<f32>::fetch_add`).
pub fn supports_f32_atomic_add(t: &CubeTensor) -> bool {
    use cubecl::features::AtomicUsage;
    use cubecl::ir::{ElemType, FloatKind, Type};
    t.client
        .properties()
        .atomic_type_usage(Type::atomic(Type::new(ElemType::Float(FloatKind::F32))))
        .contains(AtomicUsage::Add)
}
