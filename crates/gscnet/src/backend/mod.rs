//! CPU backends: one kernel implementation ([`crate::cpu`]) registered for NdArray and Flex
//! through thin adapters that borrow the primitives' buffers (no `TensorData` round trip).

#[cfg(feature = "flex")]
mod flex;
#[cfg(feature = "ndarray")]
mod ndarray;

/// Borrow the six scan inputs of a CPU backend as [`crate::cpu::scan::ScanInputs`] bound to
/// `$s` while `$body` runs.
#[allow(unused_macros)]
macro_rules! with_scan_inputs {
    ($read:path, $dims:path, $x:expr, $delta:expr, $a_log:expr, $b:expr, $c:expr, $d:expr,
     $softplus:expr, |$s:ident| $body:expr) => {{
        let (xd, ad) = ($dims($x), $dims($a_log));
        let dims = $crate::cpu::scan::ScanDims {
            k: xd[0],
            m: xd[1],
            e: xd[2],
            n: ad[1],
        };
        $read($x, |x| {
            $read($delta, |delta| {
                $read($a_log, |a_log| {
                    $read($b, |b| {
                        $read($c, |c| {
                            $read($d, |d| {
                                let $s = $crate::cpu::scan::ScanInputs {
                                    dims,
                                    x,
                                    delta,
                                    a_log,
                                    b,
                                    c,
                                    d,
                                    softplus: $softplus,
                                };
                                $body
                            })
                        })
                    })
                })
            })
        })
    }};
}
#[allow(unused_imports)]
pub(crate) use with_scan_inputs;

/// Implements [`crate::ops::SpectralOps`] for a CPU backend given `read(&tensor, |&[f32]| ..)`,
/// `write(Vec<f32>, shape)` and `dims(&tensor) -> Vec<usize>`.
#[allow(unused_macros)]
macro_rules! impl_cpu_spectral_ops {
    ($backend:ty, $read:path, $write:path, $dims:path) => {
        impl $crate::ops::SpectralOps for $backend {
            fn selective_scan(
                x: FloatTensor<Self>,
                delta: FloatTensor<Self>,
                a_log: FloatTensor<Self>,
                b: FloatTensor<Self>,
                c: FloatTensor<Self>,
                d: FloatTensor<Self>,
                softplus: bool,
            ) -> FloatTensor<Self> {
                let shape = $dims(&x);
                let y = $crate::backend::with_scan_inputs!(
                    $read,
                    $dims,
                    &x,
                    &delta,
                    &a_log,
                    &b,
                    &c,
                    &d,
                    softplus,
                    |s| $crate::cpu::scan::scan_forward(&s)
                );
                $write(y, shape)
            }

            fn selective_scan_backward(
                x: FloatTensor<Self>,
                delta: FloatTensor<Self>,
                a_log: FloatTensor<Self>,
                b: FloatTensor<Self>,
                c: FloatTensor<Self>,
                d: FloatTensor<Self>,
                softplus: bool,
                grad: FloatTensor<Self>,
            ) -> (
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
                FloatTensor<Self>,
            ) {
                let g = $crate::backend::with_scan_inputs!(
                    $read,
                    $dims,
                    &x,
                    &delta,
                    &a_log,
                    &b,
                    &c,
                    &d,
                    softplus,
                    |s| $read(&grad, |grad| $crate::cpu::scan::scan_backward(&s, grad))
                );
                (
                    $write(g.x, $dims(&x)),
                    $write(g.delta, $dims(&delta)),
                    $write(g.a_log, $dims(&a_log)),
                    $write(g.b, $dims(&b)),
                    $write(g.c, $dims(&c)),
                    $write(g.d, $dims(&d)),
                )
            }

            fn spectral_conv_silu(
                u: FloatTensor<Self>,
                w: FloatTensor<Self>,
                bias: FloatTensor<Self>,
            ) -> FloatTensor<Self> {
                let (shape, wd) = ($dims(&u), $dims(&w));
                let dims = $crate::cpu::conv::ConvDims {
                    k: shape[0],
                    m: shape[1],
                    e: shape[2],
                    j: wd[1],
                };
                let y = $read(&u, |u| {
                    $read(&w, |w| {
                        $read(&bias, |bias| {
                            $crate::cpu::conv::conv_silu_forward(dims, u, w, bias)
                        })
                    })
                });
                $write(y, shape)
            }

            fn spectral_conv_silu_backward(
                u: FloatTensor<Self>,
                w: FloatTensor<Self>,
                bias: FloatTensor<Self>,
                grad: FloatTensor<Self>,
            ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
                let (shape, wd) = ($dims(&u), $dims(&w));
                let dims = $crate::cpu::conv::ConvDims {
                    k: shape[0],
                    m: shape[1],
                    e: shape[2],
                    j: wd[1],
                };
                let g = $read(&u, |u| {
                    $read(&w, |w| {
                        $read(&bias, |bias| {
                            $read(&grad, |grad| {
                                $crate::cpu::conv::conv_silu_backward(dims, u, w, bias, grad)
                            })
                        })
                    })
                });
                (
                    $write(g.u, shape),
                    $write(g.w, wd),
                    $write(g.bias, $dims(&bias)),
                )
            }
        }
    };
}
#[allow(unused_imports)]
pub(crate) use impl_cpu_spectral_ops;
