//! What Prism's custom Burn ops (`prism-render`, `prism-gscnet`) share, written once:
//!
//! * [`simd`]: whether the CPU runs the AVX2+FMA variants of the CPU kernels;
//! * [`cpu`]: f32 buffers of the CPU backends' tensors ([`cpu::CpuFloat`], implemented for Flex
//!   and NdArray), so one kernel implementation serves both;
//! * [`autodiff`]: recording a custom op on Burn's autodiff graph and registering the gradients
//!   its hand-written backward returns.

pub mod autodiff;
pub mod cpu;
pub mod simd;
