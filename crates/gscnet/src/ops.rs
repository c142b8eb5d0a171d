//! The Burn backend extension for GSC-Net's fused CPU kernels ([`crate::cpu`]): the selective
//! scan, the spectral depthwise convolution + SiLU and the element-wise activations (GSC-Net's
//! SiLU, and the Gaussians' softplus and bounded sigmoid, which `prism-recon` applies through
//! [`activate`]), each with a hand-written backward op.
//! Registered for NdArray, Flex and Autodiff over either; the functions below are what the
//! modules call.

// The NdArray selector names burn-ndarray, deprecated in Burn 0.22 (Flex is its successor).
#![allow(deprecated)]

use burn::backend::{Backend, Dispatch, ExtensionType, backend_extension, tensor::FloatTensor};
use burn::tensor::Tensor;

/// The tensors of a selective scan: what [`SpectralOps::selective_scan`] takes and
/// [`SpectralOps::selective_scan_backward`] returns as their gradients (same shapes).
#[derive(ExtensionType)]
pub struct ScanTensors<B: Backend> {
    /// Token inputs x `[K, M, E]` (K Gaussians, M spectral positions, E channels).
    pub x: FloatTensor<B>,
    /// Steps Δ `[K, M, E]` (Δ > 0), or raw steps z with Δ = softplus(z) when `softplus` is set.
    pub delta: FloatTensor<B>,
    /// The state matrix as A_log `[E, N]`, `A = −exp(A_log)` (per channel and state).
    pub a_log: FloatTensor<B>,
    /// Input projections B `[K, M, N]`.
    pub b: FloatTensor<B>,
    /// Output projections C `[K, M, N]`.
    pub c: FloatTensor<B>,
    /// Skip weights D `[E]`.
    pub d: FloatTensor<B>,
}

impl<B: Backend> ScanTensors<B> {
    /// The six tensors in field order (x, Δ, A_log, B, C, D).
    pub fn into_array(self) -> [FloatTensor<B>; 6] {
        [self.x, self.delta, self.a_log, self.b, self.c, self.d]
    }

    /// The inverse of [`ScanTensors::into_array`].
    pub fn from_array([x, delta, a_log, b, c, d]: [FloatTensor<B>; 6]) -> Self {
        Self {
            x,
            delta,
            a_log,
            b,
            c,
            d,
        }
    }
}

/// Fused spectral kernels. Backward kernels are ops of their own so every backend (and a later
/// CubeCL port) provides them next to the forward.
#[backend_extension(NdArray: cfg(feature = "ndarray"), Flex: cfg(feature = "flex"), Autodiff)]
pub trait SpectralOps: Backend {
    /// Selective scan of `inputs` → y `[K, M, E]`. With `softplus`, `inputs.delta` holds raw
    /// steps z and Δ = softplus(z).
    fn selective_scan(
        #[extension_type] inputs: ScanTensors<Self>,
        softplus: bool,
    ) -> FloatTensor<Self>;

    /// Gradients of `⟨grad, selective_scan(..)⟩` with respect to every input (Δ: of the raw
    /// step z when `softplus`).
    fn selective_scan_backward(
        #[extension_type] inputs: ScanTensors<Self>,
        softplus: bool,
        grad: FloatTensor<Self>,
    ) -> ScanTensors<Self>;

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

    /// The curve table `table [R, M]` (nodes spaced `h` from −1 − h) read at every û of
    /// `u [K]` by cubic convolution ([`crate::cpu::table`]) → `[K, M]`.
    fn table_lookup(table: FloatTensor<Self>, u: FloatTensor<Self>, h: f32) -> FloatTensor<Self>;

    /// Gradients `(table, u)` of `⟨grad, table_lookup(..)⟩`.
    fn table_lookup_backward(
        table: FloatTensor<Self>,
        u: FloatTensor<Self>,
        h: f32,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// `kind` of every element of `x` (any shape).
    fn activate(x: FloatTensor<Self>, kind: Activation) -> FloatTensor<Self>;

    /// The gradient of `⟨grad, activate(x, kind)⟩` with respect to `x`.
    fn activate_backward(
        x: FloatTensor<Self>,
        kind: Activation,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
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
    let inputs = ScanTensors {
        x: x.into_dispatch(),
        delta: delta.into_dispatch(),
        a_log: a_log.into_dispatch(),
        b: b.into_dispatch(),
        c: c.into_dispatch(),
        d: d.into_dispatch(),
    };
    Tensor::from_dispatch(Dispatch::selective_scan(inputs, softplus))
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

/// The fused cubic table lookup (shapes checked by the caller, [`crate::model`]): `table`
/// `[R, M]` with nodes `û_j = −1 + (j − 1)·h`, read at every û of `u` `[K]` → `[K, M]`.
pub(crate) fn table_lookup(table: Tensor<2>, u: Tensor<1>, h: f32) -> Tensor<2> {
    if !crate::composed::has_fused_kernels(&u.device()) {
        return crate::composed::table_lookup(table, u, h);
    }
    Tensor::from_dispatch(Dispatch::table_lookup(
        table.into_dispatch(),
        u.into_dispatch(),
        h,
    ))
}

pub use crate::cpu::activation::Activation;

/// `kind` of every element of `x` as one fused op: one pass forward, one backward,
/// multi-threaded on the CPU backends ([`crate::cpu::activation`]); Burn's composed form
/// ([`crate::composed::activate`]) on wgpu.
pub fn activate<const D: usize>(x: Tensor<D>, kind: Activation) -> Tensor<D> {
    if !crate::composed::has_fused_kernels(&x.device()) {
        return crate::composed::activate(x, kind);
    }
    Tensor::from_dispatch(Dispatch::activate(x.into_dispatch(), kind))
}

/// SiLU, `x σ(x)` ([`activate`]): every SiLU of GSC-Net goes through it.
pub fn silu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    activate(x, Activation::Silu)
}
