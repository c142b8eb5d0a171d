//! CPU backends: one kernel implementation ([`crate::cpu`]) registered for every CPU backend
//! through [`CpuFloat`], which borrows the tensors' f32 buffers (no `TensorData` round trip).

#[cfg(any(feature = "flex", feature = "ndarray"))]
use prism_kernel::cpu::CpuFloat;

/// The scan tensors of a CPU backend as [`crate::cpu::scan::ScanInputs`].
#[cfg(any(feature = "flex", feature = "ndarray"))]
fn with_scan_inputs<B: CpuFloat, R>(
    t: &crate::ops::ScanTensors<B>,
    softplus: bool,
    f: impl FnOnce(&crate::cpu::scan::ScanInputs) -> R,
) -> R {
    let inputs = [&t.x, &t.delta, &t.a_log, &t.b, &t.c, &t.d];
    let (xd, ad) = (B::dims(inputs[0]), B::dims(inputs[2]));
    let dims = crate::cpu::scan::ScanDims {
        k: xd[0],
        m: xd[1],
        e: xd[2],
        n: ad[1],
    };
    B::with_values(inputs, |[x, delta, a_log, b, c, d]| {
        f(&crate::cpu::scan::ScanInputs {
            dims,
            x,
            delta,
            a_log,
            b,
            c,
            d,
            softplus,
        })
    })
}

/// The convolution's sizes from `u [K, M, E]` and `w [E, J]`.
#[cfg(any(feature = "flex", feature = "ndarray"))]
fn conv_dims(u: &[usize], w: &[usize]) -> crate::cpu::conv::ConvDims {
    crate::cpu::conv::ConvDims {
        k: u[0],
        m: u[1],
        e: u[2],
        j: w[1],
    }
}

/// The table's sizes from its shape `[R, M]` and node spacing `h`.
#[cfg(any(feature = "flex", feature = "ndarray"))]
fn table_dims(shape: &[usize], h: f32) -> crate::cpu::table::TableDims {
    crate::cpu::table::TableDims {
        rows: shape[0],
        m: shape[1],
        h,
    }
}

/// Implements [`crate::ops::SpectralOps`] for a CPU backend (one that implements [`CpuFloat`]).
#[cfg(any(feature = "flex", feature = "ndarray"))]
macro_rules! impl_cpu_spectral_ops {
    ($backend:ty) => {
        impl $crate::ops::SpectralOps for $backend {
            fn selective_scan(
                inputs: $crate::ops::ScanTensors<Self>,
                softplus: bool,
            ) -> FloatTensor<Self> {
                let y =
                    with_scan_inputs::<Self, _>(&inputs, softplus, $crate::cpu::scan::scan_forward);
                Self::tensor(y, Self::dims(&inputs.x))
            }

            fn selective_scan_backward(
                inputs: $crate::ops::ScanTensors<Self>,
                softplus: bool,
                grad: FloatTensor<Self>,
            ) -> $crate::ops::ScanTensors<Self> {
                let gy = Self::values(&grad);
                let g = with_scan_inputs::<Self, _>(&inputs, softplus, |s| {
                    $crate::cpu::scan::scan_backward(s, &gy)
                });
                $crate::ops::ScanTensors {
                    x: Self::tensor(g.x, Self::dims(&inputs.x)),
                    delta: Self::tensor(g.delta, Self::dims(&inputs.delta)),
                    a_log: Self::tensor(g.a_log, Self::dims(&inputs.a_log)),
                    b: Self::tensor(g.b, Self::dims(&inputs.b)),
                    c: Self::tensor(g.c, Self::dims(&inputs.c)),
                    d: Self::tensor(g.d, Self::dims(&inputs.d)),
                }
            }

            fn spectral_conv_silu(
                u: FloatTensor<Self>,
                w: FloatTensor<Self>,
                bias: FloatTensor<Self>,
            ) -> FloatTensor<Self> {
                let shape = Self::dims(&u);
                let dims = conv_dims(&shape, &Self::dims(&w));
                let y = Self::with_values([&u, &w, &bias], |[u, w, bias]| {
                    $crate::cpu::conv::conv_silu_forward(dims, u, w, bias)
                });
                Self::tensor(y, shape)
            }

            fn spectral_conv_silu_backward(
                u: FloatTensor<Self>,
                w: FloatTensor<Self>,
                bias: FloatTensor<Self>,
                grad: FloatTensor<Self>,
            ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
                let (shape, wd) = (Self::dims(&u), Self::dims(&w));
                let dims = conv_dims(&shape, &wd);
                let g = Self::with_values([&u, &w, &bias, &grad], |[u, w, bias, grad]| {
                    $crate::cpu::conv::conv_silu_backward(dims, u, w, bias, grad)
                });
                (
                    Self::tensor(g.u, shape),
                    Self::tensor(g.w, wd),
                    Self::tensor(g.bias, Self::dims(&bias)),
                )
            }

            fn table_lookup(
                table: FloatTensor<Self>,
                u: FloatTensor<Self>,
                h: f32,
            ) -> FloatTensor<Self> {
                let dims = table_dims(&Self::dims(&table), h);
                let y = Self::with_values([&table, &u], |[table, u]| {
                    $crate::cpu::table::lookup_forward(dims, table, u)
                });
                Self::tensor(y, vec![Self::dims(&u)[0], dims.m])
            }

            fn table_lookup_backward(
                table: FloatTensor<Self>,
                u: FloatTensor<Self>,
                h: f32,
                grad: FloatTensor<Self>,
            ) -> (FloatTensor<Self>, FloatTensor<Self>) {
                let (shape, ushape) = (Self::dims(&table), Self::dims(&u));
                let dims = table_dims(&shape, h);
                let (gt, gu) = Self::with_values([&table, &u, &grad], |[table, u, grad]| {
                    $crate::cpu::table::lookup_backward(dims, table, u, grad)
                });
                (Self::tensor(gt, shape), Self::tensor(gu, ushape))
            }

            fn activate(x: FloatTensor<Self>, kind: $crate::ops::Activation) -> FloatTensor<Self> {
                let y = Self::with_values([&x], |[x]| $crate::cpu::activation::forward(kind, x));
                Self::tensor(y, Self::dims(&x))
            }

            fn activate_backward(
                x: FloatTensor<Self>,
                kind: $crate::ops::Activation,
                grad: FloatTensor<Self>,
            ) -> FloatTensor<Self> {
                let g = Self::with_values([&x, &grad], |[x, grad]| {
                    $crate::cpu::activation::backward(kind, x, grad)
                });
                Self::tensor(g, Self::dims(&x))
            }
        }
    };
}

#[cfg(feature = "flex")]
mod flex {
    use super::*;
    use burn::backend::{Flex, tensor::FloatTensor};
    impl_cpu_spectral_ops!(Flex);
}

// burn-ndarray is deprecated in Burn 0.22 (Flex is its successor); kept while it exists.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
mod ndarray {
    use super::*;
    use burn::backend::{NdArray, tensor::FloatTensor};
    impl_cpu_spectral_ops!(NdArray);
}
