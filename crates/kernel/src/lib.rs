//! What Prism's custom Burn ops (`prism-render`, `prism-gscnet`, `prism-field`) share, written once
//! (all but [`simd`] behind the `burn` feature, so `prism-domain`'s projector uses [`simd`] without
//! Burn):
//!
//! * [`simd`]: whether the CPU runs the AVX2+FMA variants of the CPU kernels;
//! * [`cpu`]: f32 buffers of the CPU backends' tensors ([`cpu::CpuFloat`], implemented for Flex
//!   and NdArray), so one kernel implementation serves both, and the ordered sum of per-task
//!   partial gradients ([`cpu::sum_partials`]);
//! * [`autodiff`]: recording a custom op on Burn's autodiff graph and registering the gradients
//!   its hand-written backward returns;
//! * `cube` (feature `cube`): launch helpers of the CubeCL kernels (buffers, 1-D launch sizes,
//!   the f32 atomic-add capability).

#[cfg(feature = "burn")]
pub mod autodiff;
#[cfg(feature = "burn")]
pub mod cpu;
#[cfg(feature = "cube")]
pub mod cube;
pub mod simd;
