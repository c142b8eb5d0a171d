//! CPU backends: the kernels of [`crate::cpu`] registered for every CPU backend through
//! [`CpuFloat`], which borrows the tensors' f32 buffers.

#[cfg(any(feature = "flex", feature = "ndarray"))]
macro_rules! impl_cpu_field_ops {
    ($backend:ty) => {
        impl $crate::ops::FieldOps for $backend {
            fn hash_grid_encode(
                points: FloatTensor<Self>,
                table: FloatTensor<Self>,
                grid: HashGrid,
            ) -> FloatTensor<Self> {
                let n = Self::dims(&points)[0];
                let out =
                    Self::with_values([&points, &table], |[p, t]| $crate::cpu::encode(&grid, p, t));
                Self::tensor(out, vec![n, grid.width()])
            }

            fn hash_grid_encode_backward(
                points: FloatTensor<Self>,
                grid: HashGrid,
                grad: FloatTensor<Self>,
            ) -> FloatTensor<Self> {
                let out = Self::with_values([&points, &grad], |[p, g]| {
                    $crate::cpu::encode_backward(&grid, p, g)
                });
                Self::tensor(out, vec![grid.rows(), grid.features])
            }

            fn field_mlp(
                enc: FloatTensor<Self>,
                params: FloatTensor<Self>,
                layout: MlpLayout,
            ) -> FloatTensor<Self> {
                let n = Self::dims(&enc)[0];
                let out = Self::with_values([&enc, &params], |[e, p]| {
                    $crate::mlp::cpu_forward(&layout, e, p)
                });
                Self::tensor(out, vec![n, 1])
            }

            fn field_mlp_backward(
                enc: FloatTensor<Self>,
                params: FloatTensor<Self>,
                layout: MlpLayout,
                grad: FloatTensor<Self>,
            ) -> (FloatTensor<Self>, FloatTensor<Self>) {
                let (n, p) = (Self::dims(&enc)[0], Self::dims(&params)[0]);
                let (d_enc, d_params) = Self::with_values([&enc, &params, &grad], |[e, w, g]| {
                    $crate::mlp::cpu_backward(&layout, e, w, g)
                });
                (
                    Self::tensor(d_enc, vec![n, layout.input]),
                    Self::tensor(d_params, vec![p]),
                )
            }
        }
    };
}

#[cfg(feature = "flex")]
mod flex {
    use crate::grid::HashGrid;
    use crate::mlp::MlpLayout;
    use burn::backend::{Flex, tensor::FloatTensor};
    use prism_kernel::cpu::CpuFloat;
    impl_cpu_field_ops!(Flex);
}

// burn-ndarray is deprecated in Burn 0.22 (Flex is its successor); kept while it exists.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
mod ndarray {
    use crate::grid::HashGrid;
    use crate::mlp::MlpLayout;
    use burn::backend::{NdArray, tensor::FloatTensor};
    use prism_kernel::cpu::CpuFloat;
    impl_cpu_field_ops!(NdArray);
}
