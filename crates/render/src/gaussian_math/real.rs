//! The number type of the per-Gaussian math: one `f64`, or four Gaussians at once in
//! [`F64x4`] lanes.
//!
//! The lane type exists for speed: a splat's preparation and its chain rule are chains of
//! dependent divisions and square roots, so one Gaussian at a time leaves the core waiting on
//! their latency; four independent chains side by side fill it. Every lane operation is the
//! IEEE `f64` operation of the scalar code (no fused multiply-adds, the same order), so a
//! Gaussian's result is bit for bit the same whichever type computed it.
//!
//! Validity travels as a [`Real::Mask`] beside the values instead of an early return: a lane
//! whose Gaussian is degenerate computes on regardless, and its result is discarded.

use std::ops::{Add, BitAnd, Div, Mul, Neg, Sub};

/// An `f64`, or several computed lane-wise.
pub trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// Per-lane truth values.
    type Mask: Copy + BitAnd<Output = Self::Mask>;
    /// `v` in every lane.
    fn splat(v: f64) -> Self;
    fn sqrt(self) -> Self;
    /// `self > o` (false where either is NaN).
    fn gt(self, o: Self) -> Self::Mask;
    fn is_finite(self) -> Self::Mask;
}

impl Real for f64 {
    type Mask = bool;

    #[inline(always)]
    fn splat(v: f64) -> Self {
        v
    }

    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }

    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        self > o
    }

    #[inline(always)]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
}

/// Number of lanes of [`F64x4`].
pub const F64_LANES: usize = 4;

/// Four `f64` lanes. Compiled inside a function with AVX enabled, each operation is one
/// 256-bit instruction; elsewhere two SSE2 ones.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct F64x4(pub [f64; F64_LANES]);

/// Per-lane truth values of [`F64x4`], each lane all ones (true) or all zeros (false): the
/// form a vector comparison gives, so comparisons and `&` stay in vector registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mask4([u64; F64_LANES]);

impl Mask4 {
    /// Lane `j`.
    #[inline(always)]
    pub fn lane(self, j: usize) -> bool {
        self.0[j] != 0
    }

    #[inline(always)]
    fn from_fn(mut f: impl FnMut(usize) -> bool) -> Self {
        Self(std::array::from_fn(|j| if f(j) { u64::MAX } else { 0 }))
    }
}

impl BitAnd for Mask4 {
    type Output = Self;

    #[inline(always)]
    fn bitand(self, o: Self) -> Self {
        Self(std::array::from_fn(|j| self.0[j] & o.0[j]))
    }
}

impl F64x4 {
    /// Lane `j` of every value is `f(j)`.
    #[inline(always)]
    pub fn from_fn(f: impl FnMut(usize) -> f64) -> Self {
        Self(super::arr4(f))
    }

    /// `N` values of four items in lanes: lane `j` of value `q` is `f(j)[q]`.
    #[inline(always)]
    pub fn gather<const N: usize>(f: impl FnMut(usize) -> [f64; N]) -> [Self; N] {
        let items: [[f64; N]; F64_LANES] = super::arr4(f);
        std::array::from_fn(|q| Self::from_fn(|j| items[j][q]))
    }

    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f64, f64) -> f64) -> Self {
        Self(std::array::from_fn(|j| f(self.0[j], o.0[j])))
    }
}

macro_rules! lane_op {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for F64x4 {
            type Output = Self;

            #[inline(always)]
            fn $method(self, o: Self) -> Self {
                self.zip(o, |a, b| a $op b)
            }
        }
    };
}

lane_op!(Add, add, +);
lane_op!(Sub, sub, -);
lane_op!(Mul, mul, *);
lane_op!(Div, div, /);

impl Neg for F64x4 {
    type Output = Self;

    #[inline(always)]
    fn neg(self) -> Self {
        Self(self.0.map(|a| -a))
    }
}

impl Real for F64x4 {
    type Mask = Mask4;

    #[inline(always)]
    fn splat(v: f64) -> Self {
        Self([v; F64_LANES])
    }

    #[inline(always)]
    fn sqrt(self) -> Self {
        Self(self.0.map(f64::sqrt))
    }

    #[inline(always)]
    fn gt(self, o: Self) -> Mask4 {
        Mask4::from_fn(|j| self.0[j] > o.0[j])
    }

    #[inline(always)]
    fn is_finite(self) -> Mask4 {
        Mask4::from_fn(|j| self.0[j].is_finite())
    }
}
