//! Eight f32 lanes for the pixel-row kernels: one AVX2 register ([`Avx2`], x86-64 only) or a
//! plain array ([`Portable`], any target, unfused multiply-adds).
//!
//! The kernels are written once, generic over [`Lanes`], and compiled for both types by the
//! [`dispatched!`] macro. Explicit lanes, rather than leaving array loops to
//! the auto-vectoriser, because LLVM's SLP vectoriser splits loop-carried 8-lane accumulators
//! into 2- and 4-lane pieces (the auto-vectorised backward kernel ran in xmm registers, about
//! 3× slower in a perf profile of one 50 000-Gaussian view).

use super::{MulAdd, Separate, exp_neg_with};

pub(crate) use prism_kernel::simd::has_avx2_fma as has_avx2;

/// Generates a dispatcher `$name` over one body compiled twice: for the build's baseline target
/// with [`Portable`] lanes (unfused multiply-adds) and with AVX2+FMA enabled and [`Avx2`] lanes
/// (fused ones), chosen at run time by [`has_avx2`]. The variants differ in rounding only.
/// The expansion names `Lanes`, `Portable`, `Avx2` and `has_avx2`: import them where it is used.
macro_rules! dispatched {
    ($(#[$doc:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $body:block) => {
        $(#[$doc])*
        $vis fn $name($($arg: $ty),*) {
            #[inline(always)]
            fn body<L: Lanes>($($arg: $ty),*) $body
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            fn wide($($arg: $ty),*) {
                body::<Avx2>($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            if has_avx2() {
                // SAFETY: `has_avx2` verified that the CPU supports AVX2 and FMA.
                return unsafe { wide($($arg),*) };
            }
            body::<Portable>($($arg),*)
        }
    };
}
pub(crate) use dispatched;

/// Lanes per vector.
pub(crate) const LANES: usize = 8;

/// An upstream gradient as the backward row kernels read it: `values` (rows padded so a lane
/// block starting at any pixel or voxel of a row lies inside it) and whether all of it is
/// `finite` (then the kernels skip the select that keeps non-finite products out of their sums,
/// see [`Lanes::zero_outside`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct UpstreamGrad<'a> {
    pub(crate) values: &'a [f32],
    pub(crate) finite: bool,
}

/// Counts the rows a backward kernel sums in f32 lane accumulators and says when to widen them
/// into f64: every `every` rows (so each f32 partial sum holds a bounded number of terms), and
/// once more at the end if rows are pending.
pub(crate) struct RowBatches {
    pending: usize,
    every: usize,
}

impl RowBatches {
    pub(crate) fn new(every: usize) -> Self {
        Self { pending: 0, every }
    }

    /// Count one row; whether the sums are due now.
    #[inline(always)]
    pub(crate) fn due(&mut self) -> bool {
        self.pending += 1;
        let due = self.pending == self.every;
        if due {
            self.pending = 0;
        }
        due
    }

    /// Whether rows were summed since the last widening.
    pub(crate) fn pending(&self) -> bool {
        self.pending > 0
    }
}

/// Add each lane block's sum (widened to f64) to `acc` and zero the blocks.
#[inline(always)]
pub(crate) fn drain<L: Lanes>(lanes: &mut [[f32; LANES]], acc: &mut [f64]) {
    for (o, l) in acc.iter_mut().zip(lanes.iter_mut()) {
        *o += L::load(l).sum();
        *l = [0.0; LANES];
    }
}

/// An 8-lane f32 vector. Arithmetic is lane-wise IEEE f32; `mul_add` is fused for [`Avx2`] and
/// two roundings for [`Portable`].
pub(crate) trait Lanes: Copy {
    fn splat(v: f32) -> Self;
    fn load(a: &[f32; LANES]) -> Self;
    fn store(self, a: &mut [f32; LANES]);
    fn add(self, o: Self) -> Self;
    fn mul(self, o: Self) -> Self;
    /// `self · b + c`.
    fn mul_add(self, b: Self, c: Self) -> Self;
    /// `self` where `a ≤ b` (false for NaN), else `+0`.
    fn keep_le(self, a: Self, b: Self) -> Self;
    /// `self` where `e ≠ 0`, else `+0` (a select, so a non-finite `self` there gives 0).
    fn keep_nonzero(self, e: Self) -> Self;
    /// `self · e` where `e ≠ 0`, else `+0`, for a product whose other factor (`self / e`) is
    /// `finite` everywhere when the flag says so: a finite value times `e = +0` is ±0, which
    /// leaves any sum it enters unchanged, so the select is only paid for non-finite factors.
    #[inline(always)]
    fn zero_outside(self, e: Self, finite: bool) -> Self {
        if finite { self } else { self.keep_nonzero(e) }
    }
    /// [`super::exp_neg`] of every lane (same polynomial, this type's `mul_add`).
    fn exp_neg(self) -> Self;

    /// `[Σ a, Σ dx·a, Σ dx²·a, Σ b, Σ dx·b, Σ c]` over the lanes in f64: every lane widened,
    /// products in f64, sums pairwise (lanes `j` and `j + 4`, then `j + 2`, then `j + 1`).
    #[inline(always)]
    fn moments(dx: Self, a: Self, b: Self, c: Self) -> [f64; 6] {
        let [dx, a, b, c] = [dx, a, b, c].map(|v| v.to_array().map(|x| x as f64));
        let x: [f64; LANES] = std::array::from_fn(|j| dx[j] * a[j]);
        let xx: [f64; LANES] = std::array::from_fn(|j| dx[j] * x[j]);
        let xb: [f64; LANES] = std::array::from_fn(|j| dx[j] * b[j]);
        [a, x, xx, b, xb, c].map(sum_pairwise)
    }

    /// `Σ self` over the lanes in f64 (widened, summed as in [`Lanes::moments`]).
    #[inline(always)]
    fn sum(self) -> f64 {
        sum_pairwise(self.to_array().map(|x| x as f64))
    }

    #[inline(always)]
    fn zero() -> Self {
        Self::splat(0.0)
    }

    #[inline(always)]
    fn to_array(self) -> [f32; LANES] {
        let mut a = [0.0; LANES];
        self.store(&mut a);
        a
    }
}

/// Sum of 8 f64 by halving (`a[j] += a[j + w]` for w = 4, 2, 1): independent adds that
/// vectorise, and the order the AVX2 reductions use.
#[inline(always)]
fn sum_pairwise(v: [f64; LANES]) -> f64 {
    let mut a = v;
    let mut w = LANES / 2;
    while w > 0 {
        for j in 0..w {
            a[j] += a[j + w];
        }
        w /= 2;
    }
    a[0]
}

/// Plain-array lanes for the baseline build.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Portable([f32; LANES]);

impl Portable {
    #[inline(always)]
    fn map2(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        Self(std::array::from_fn(|j| f(self.0[j], o.0[j])))
    }
}

impl Lanes for Portable {
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Self([v; LANES])
    }
    #[inline(always)]
    fn load(a: &[f32; LANES]) -> Self {
        Self(*a)
    }
    #[inline(always)]
    fn store(self, a: &mut [f32; LANES]) {
        *a = self.0;
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self.map2(o, |a, b| a + b)
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        self.map2(o, |a, b| a * b)
    }
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        Self(std::array::from_fn(|j| {
            Separate::mul_add(self.0[j], b.0[j], c.0[j])
        }))
    }
    #[inline(always)]
    fn keep_le(self, a: Self, b: Self) -> Self {
        Self(std::array::from_fn(|j| {
            if a.0[j] <= b.0[j] { self.0[j] } else { 0.0 }
        }))
    }
    #[inline(always)]
    fn keep_nonzero(self, e: Self) -> Self {
        Self(std::array::from_fn(|j| {
            if e.0[j] != 0.0 { self.0[j] } else { 0.0 }
        }))
    }
    #[inline(always)]
    fn exp_neg(self) -> Self {
        Self(self.0.map(exp_neg_with::<Separate>))
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use avx2::Avx2;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{LANES, Lanes};

    /// Whether this CPU runs AVX2 and FMA (the type invariant, checked in debug builds where
    /// values are created).
    fn supported() -> bool {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }

    /// Lanes 0–3 and 4–7 of `v` as f64.
    #[inline(always)]
    fn widen(v: __m256) -> (__m256d, __m256d) {
        // SAFETY: AVX is available (type invariant).
        unsafe {
            (
                _mm256_cvtps_pd(_mm256_castps256_ps128(v)),
                _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(v)),
            )
        }
    }

    /// `Σ (lo + hi)` in the pairwise order of `sum_pairwise`.
    #[inline(always)]
    fn sum(lo: __m256d, hi: __m256d) -> f64 {
        // SAFETY: AVX is available (type invariant).
        unsafe {
            let s4 = _mm256_add_pd(lo, hi);
            let s2 = _mm_add_pd(_mm256_castpd256_pd128(s4), _mm256_extractf128_pd::<1>(s4));
            _mm_cvtsd_f64(_mm_add_sd(s2, _mm_unpackhi_pd(s2, s2)))
        }
    }

    /// One AVX2 register of f32 lanes, with fused multiply-adds.
    ///
    /// Invariant (crate-private type): values of this type are only created inside functions
    /// compiled with `target_feature(enable = "avx2,fma")` that run after the CPU was checked
    /// for AVX2 and FMA (the `wide` variants of `dispatched!`), so every intrinsic below is
    /// supported where it executes.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Avx2(__m256);

    impl Lanes for Avx2 {
        #[inline(always)]
        fn splat(v: f32) -> Self {
            debug_assert!(supported(), "Avx2 lanes on a CPU without AVX2+FMA");
            // SAFETY: AVX is available (type invariant).
            Self(unsafe { _mm256_set1_ps(v) })
        }
        #[inline(always)]
        fn load(a: &[f32; LANES]) -> Self {
            debug_assert!(supported(), "Avx2 lanes on a CPU without AVX2+FMA");
            // SAFETY: AVX is available (type invariant); `a` holds 8 readable f32.
            Self(unsafe { _mm256_loadu_ps(a.as_ptr()) })
        }
        #[inline(always)]
        fn store(self, a: &mut [f32; LANES]) {
            // SAFETY: AVX is available (type invariant); `a` holds 8 writable f32.
            unsafe { _mm256_storeu_ps(a.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            // SAFETY: AVX is available (type invariant).
            Self(unsafe { _mm256_add_ps(self.0, o.0) })
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            // SAFETY: AVX is available (type invariant).
            Self(unsafe { _mm256_mul_ps(self.0, o.0) })
        }
        #[inline(always)]
        fn mul_add(self, b: Self, c: Self) -> Self {
            // SAFETY: FMA is available (type invariant).
            Self(unsafe { _mm256_fmadd_ps(self.0, b.0, c.0) })
        }
        #[inline(always)]
        fn keep_le(self, a: Self, b: Self) -> Self {
            // SAFETY: AVX is available (type invariant). Ordered compare: NaN gives false.
            Self(unsafe { _mm256_and_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(a.0, b.0), self.0) })
        }
        #[inline(always)]
        fn keep_nonzero(self, e: Self) -> Self {
            // SAFETY: AVX is available (type invariant). Unordered not-equal: NaN ≠ 0 keeps
            // `self`, as the scalar `e != 0.0` does.
            Self(unsafe {
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_NEQ_UQ>(e.0, _mm256_setzero_ps()),
                    self.0,
                )
            })
        }
        #[inline(always)]
        fn moments(dx: Self, a: Self, b: Self, c: Self) -> [f64; 6] {
            let (dl, dh) = widen(dx.0);
            let (al, ah) = widen(a.0);
            let (bl, bh) = widen(b.0);
            let (cl, ch) = widen(c.0);
            // SAFETY: AVX is available (type invariant). Plain multiplies (no FMA), as in the
            // portable reduction.
            unsafe {
                let (xl, xh) = (_mm256_mul_pd(dl, al), _mm256_mul_pd(dh, ah));
                [
                    sum(al, ah),
                    sum(xl, xh),
                    sum(_mm256_mul_pd(dl, xl), _mm256_mul_pd(dh, xh)),
                    sum(bl, bh),
                    sum(_mm256_mul_pd(dl, bl), _mm256_mul_pd(dh, bh)),
                    sum(cl, ch),
                ]
            }
        }

        #[inline(always)]
        fn sum(self) -> f64 {
            let (lo, hi) = widen(self.0);
            sum(lo, hi)
        }

        #[inline(always)]
        fn exp_neg(self) -> Self {
            // The algorithm of `exp_neg_with::<Fused>`, lane-wise.
            const LOG2E: f32 = std::f32::consts::LOG2_E;
            const LN2_HI: f32 = 0.693_145_75;
            const LN2_LO: f32 = 1.428_606_8e-6;
            const MAGIC: f32 = 12_582_912.0;
            // SAFETY: AVX2 and FMA are available (type invariant).
            unsafe {
                // max/min return their second operand when either is NaN: NaN propagates.
                let x = _mm256_min_ps(
                    _mm256_setzero_ps(),
                    _mm256_max_ps(_mm256_set1_ps(-87.0), self.0),
                );
                let magic = _mm256_set1_ps(MAGIC);
                let t = _mm256_fmadd_ps(x, _mm256_set1_ps(LOG2E), magic);
                let n = _mm256_sub_ps(t, magic);
                let ni = _mm256_sub_epi32(_mm256_castps_si256(t), _mm256_castps_si256(magic));
                let y = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_HI), x);
                let y = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_LO), y);
                let c = |v: f32| _mm256_set1_ps(v);
                let y2 = _mm256_mul_ps(y, y);
                let y4 = _mm256_mul_ps(y2, y2);
                let lo = _mm256_fmadd_ps(
                    y2,
                    _mm256_fmadd_ps(y, c(1.0 / 6.0), c(0.5)),
                    _mm256_add_ps(y, c(1.0)),
                );
                let hi = _mm256_fmadd_ps(
                    y2,
                    c(1.0 / 720.0),
                    _mm256_fmadd_ps(y, c(1.0 / 120.0), c(1.0 / 24.0)),
                );
                let p = _mm256_fmadd_ps(y4, hi, lo);
                let scale = _mm256_slli_epi32::<23>(_mm256_add_epi32(ni, _mm256_set1_epi32(127)));
                Self(_mm256_mul_ps(p, _mm256_castsi256_ps(scale)))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both lane types against the scalar definitions, on values around the cut-offs and the
    /// exp clamp, with NaN and infinities.
    #[test]
    fn lanes_match_scalar_definitions() {
        let xs: [f32; LANES] = [
            0.0,
            -0.3,
            -4.5,
            -86.9,
            -87.5,
            f32::NEG_INFINITY,
            f32::NAN,
            -1e-30,
        ];
        let ys: [f32; LANES] = [1.0, 0.0, -2.0, f32::NAN, 3.0, 0.0, 4.5, f32::INFINITY];
        check::<Portable>(&xs, &ys, exp_neg_with::<Separate>);
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            // SAFETY: AVX2 and FMA were just detected.
            unsafe { check_avx2(&xs, &ys) };
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn check_avx2(xs: &[f32; LANES], ys: &[f32; LANES]) {
        check::<Avx2>(xs, ys, exp_neg_with::<super::super::Fused>);
    }

    #[inline(always)]
    fn check<L: Lanes>(xs: &[f32; LANES], ys: &[f32; LANES], exp: fn(f32) -> f32) {
        let (x, y) = (L::load(xs), L::load(ys));
        let same = |a: f32, b: f32| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        let e = x.exp_neg().to_array();
        let le = x.keep_le(x, y).to_array();
        let nz = y.keep_nonzero(x).to_array();
        let fma = x.mul_add(y, L::splat(1.0)).to_array();
        // The reductions: exact on small integers, whatever the order.
        let ints: [f32; LANES] = std::array::from_fn(|j| j as f32 - 3.0);
        let (i, one) = (L::load(&ints), L::splat(1.0));
        assert_eq!(i.sum(), 4.0);
        assert_eq!(L::moments(i, one, i, one), [8.0, 4.0, 44.0, 4.0, 44.0, 8.0]);
        for j in 0..LANES {
            // The lanes evaluate the scalar algorithm with the same roundings: bit-identical.
            assert!(
                same(e[j], exp(xs[j])),
                "exp lane {j}: {} vs {}",
                e[j],
                exp(xs[j])
            );
            let want = if xs[j] <= ys[j] { xs[j] } else { 0.0 };
            assert!(same(le[j], want), "keep_le lane {j}");
            let want = if xs[j] != 0.0 { ys[j] } else { 0.0 };
            assert!(same(nz[j], want), "keep_nonzero lane {j}");
            let sep = xs[j] * ys[j] + 1.0;
            let fused = xs[j].mul_add(ys[j], 1.0);
            assert!(same(fma[j], sep) || same(fma[j], fused), "mul_add lane {j}");
        }
    }
}
