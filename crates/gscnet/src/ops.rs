//! The Burn backend extension for GSC-Net's fused CPU kernels ([`crate::cpu`]): the selective
//! scan and the spectral depthwise convolution + SiLU, each with a hand-written backward op.
//! Registered for NdArray, Flex and Autodiff over either; the functions below are what the
//! modules call.

// The NdArray selector names burn-ndarray, deprecated in Burn 0.22 (Flex is its successor).
#![allow(deprecated)]

use burn::backend::{Backend, Dispatch, backend_extension, tensor::FloatTensor};
use burn::tensor::Tensor;

/// Fused spectral kernels. Backward kernels are ops of their own so every backend (and a later
/// CubeCL port) provides them next to the forward.
#[backend_extension(NdArray: cfg(feature = "ndarray"), Flex: cfg(feature = "flex"), Autodiff)]
pub trait SpectralOps: Backend {
    /// Selective scan: x, Δ `[K, M, E]`, A_log `[E, N]`, B, C `[K, M, N]`, D `[E]` → `[K, M, E]`.
    /// With `softplus`, `delta` holds raw steps z and Δ = softplus(z).
    fn selective_scan(
        x: FloatTensor<Self>,
        delta: FloatTensor<Self>,
        a_log: FloatTensor<Self>,
        b: FloatTensor<Self>,
        c: FloatTensor<Self>,
        d: FloatTensor<Self>,
        softplus: bool,
    ) -> FloatTensor<Self>;

    /// Gradients `(x, Δ, A_log, B, C, D)` of `⟨grad, selective_scan(..)⟩` (Δ: of the raw step
    /// z when `softplus`).
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
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
    );

    /// SiLU(depthwise centred conv over M): u `[K, M, E]`, w `[E, J]`, bias `[E]` → `[K, M, E]`.
    fn spectral_conv_silu(
        u: FloatTensor<Self>,
        w: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// Gradients `(u, w, bias)` of `⟨grad, spectral_conv_silu(..)⟩`.
    fn spectral_conv_silu_backward(
        u: FloatTensor<Self>,
        w: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// The fused selective scan (shapes checked by the caller, [`crate::ssm::selective_scan`]); with
/// `softplus`, `delta` holds raw steps z and Δ = softplus(z).
pub(crate) fn fused_selective_scan(
    x: Tensor<3>,
    delta: Tensor<3>,
    a_log: Tensor<2>,
    b: Tensor<3>,
    c: Tensor<3>,
    d: Tensor<1>,
    softplus: bool,
) -> Tensor<3> {
    if !crate::composed::has_fused_kernels(&x.device()) {
        return crate::composed::selective_scan(x, delta, a_log, b, c, d, softplus);
    }
    Tensor::from_dispatch(Dispatch::selective_scan(
        x.into_dispatch(),
        delta.into_dispatch(),
        a_log.into_dispatch(),
        b.into_dispatch(),
        c.into_dispatch(),
        d.into_dispatch(),
        softplus,
    ))
}

/// The fused depthwise convolution + SiLU (shapes checked by the caller,
/// [`crate::conv::spectral_conv_silu`]).
pub(crate) fn fused_conv_silu(u: Tensor<3>, w: Tensor<2>, bias: Tensor<1>) -> Tensor<3> {
    if !crate::composed::has_fused_kernels(&u.device()) {
        return crate::composed::conv_silu(u, w, bias);
    }
    Tensor::from_dispatch(Dispatch::spectral_conv_silu(
        u.into_dispatch(),
        w.into_dispatch(),
        bias.into_dispatch(),
    ))
}
