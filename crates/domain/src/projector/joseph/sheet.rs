//! Column sheets: the horizontal interpolation of one detector column's rays done once per
//! column (see the module docs of [`super`]), and the rays' linear samples in z on it (AVX2
//! gathers eight planes at a time).

use super::*;

/// Lanes of the AVX2 sheet sampler; sheets carry this many planes of slack minus one.
pub(super) const LANES: usize = 8;

/// One ray on a column sheet: plane offsets `m0..=m1`, z index `z0 + m·dz`, mm per plane `step`.
pub(super) struct SheetRay {
    pub(super) m0: usize,
    pub(super) m1: usize,
    pub(super) z0: f32,
    pub(super) dz: f32,
    pub(super) step: f32,
}

impl SheetRay {
    /// The lower z neighbour `q` (clamped to `[qlo, qhi]`) of the ray at plane `m`, and the
    /// weight `z − q` of the upper one (the vector sampler computes the same, lane by lane).
    #[inline(always)]
    pub(super) fn z_neighbour(&self, m: usize, qlo: i32, qhi: i32) -> (i32, f32) {
        let z = self.z0 + m as f32 * self.dz;
        let q = floorish(z).clamp(qlo, qhi);
        (q, z - q as f32)
    }
}

/// How one detector pixel's ray is traced.
pub(super) enum RowPlan {
    Sheet(SheetRay),
    Walk(RayWalk),
    Miss,
}

/// A column sheet: `planes` rows of `h` z-samples covering `[zlo − 1, zhi + 1]` (the end rows stay
/// zero), plus `LANES − 1` rows of slack for the vector sampler.
pub(super) struct Sheet {
    pub(super) data: Vec<f32>,
    /// Per plane: volume offset at z = `zlo` and weight of the two horizontal neighbours.
    pub(super) taps: Vec<[(usize, f32); 2]>,
    pub(super) h: usize,
    pub(super) zlo: usize,
    pub(super) zhi: usize,
}

impl Sheet {
    pub(super) fn new() -> Sheet {
        Sheet {
            data: Vec::new(),
            taps: Vec::new(),
            h: 0,
            zlo: 0,
            zhi: 0,
        }
    }

    /// Zero the sheet for `planes` planes over z in `[zlo, zhi]`.
    pub(super) fn reset(&mut self, planes: usize, zlo: usize, zhi: usize) {
        self.h = zhi - zlo + 3;
        self.zlo = zlo;
        self.zhi = zhi;
        self.data.clear();
        self.data.resize((planes + LANES - 1) * self.h, 0.0);
    }

    /// Clamp range of the lower z neighbour: `[zlo − 1, zhi]`.
    pub(super) fn q_range(&self) -> (i32, i32) {
        (self.zlo as i32 - 1, self.zhi as i32)
    }

    /// Volume offset (at z = `zlo`) and weight of the two horizontal neighbours of every plane
    /// ([`plane_taps`]).
    pub(super) fn corners(&mut self, layout: Layout, c: &ColumnWalk, jr: (usize, usize)) {
        self.taps.clear();
        let zlo = self.zlo;
        self.taps
            .extend((0..c.planes()).map(|m| plane_taps(layout, c, m, zlo, jr)));
    }

    /// Forward: `S[m][z] = Σ_corners w · V(plane, corner, z)` over the sheet's z-range. With
    /// z-fastest volumes each corner is a contiguous z-line; otherwise the loops run z-outer so
    /// that the volume is read slice by slice.
    pub(super) fn build(
        &mut self,
        vol: &[f32],
        layout: Layout,
        c: &ColumnWalk,
        jr: (usize, usize),
    ) {
        self.corners(layout, c, jr);
        let (h, sz, nzs) = (self.h, layout.stride[2], self.h - 2);
        if sz == 1 {
            for (m, taps) in self.taps.iter().enumerate() {
                let dst = &mut self.data[m * h + 1..m * h + h - 1];
                for &(base, w) in taps.iter().filter(|t| t.1 != 0.0) {
                    for (d, &v) in dst.iter_mut().zip(&vol[base..base + nzs]) {
                        *d += w * v;
                    }
                }
            }
        } else {
            for t in 0..nzs {
                for (m, taps) in self.taps.iter().enumerate() {
                    let [(b0, w0), (b1, w1)] = *taps;
                    self.data[m * h + 1 + t] += w0 * vol[b0 + t * sz] + w1 * vol[b1 + t * sz];
                }
            }
        }
    }

    /// Adjoint of [`Sheet::build`]: scatter the sheet's z-range into `acc`, same taps.
    pub(super) fn scatter(
        &mut self,
        acc: &mut [f32],
        layout: Layout,
        c: &ColumnWalk,
        jr: (usize, usize),
    ) {
        self.corners(layout, c, jr);
        let (h, sz, nzs) = (self.h, layout.stride[2], self.h - 2);
        if sz == 1 {
            for (m, taps) in self.taps.iter().enumerate() {
                let src = &self.data[m * h + 1..m * h + h - 1];
                for &(base, w) in taps.iter().filter(|t| t.1 != 0.0) {
                    for (d, &v) in acc[base..base + nzs].iter_mut().zip(src) {
                        *d += w * v;
                    }
                }
            }
        } else {
            for t in 0..nzs {
                for (m, taps) in self.taps.iter().enumerate() {
                    let v = self.data[m * h + 1 + t];
                    for &(base, w) in taps.iter().filter(|t| t.1 != 0.0) {
                        acc[base + t * sz] += w * v;
                    }
                }
            }
        }
    }

    /// `Σ_m lerp_z(S[m], z0 + m·dz) · step` (scalar).
    pub(super) fn sample(&self, r: &SheetRay) -> f32 {
        let (qlo, qhi) = self.q_range();
        let mut acc = 0.0f32;
        for m in r.m0..=r.m1 {
            let (q, f) = r.z_neighbour(m, qlo, qhi);
            let idx = m * self.h + (q - qlo) as usize;
            let (a, b) = (self.data[idx], self.data[idx + 1]);
            acc += a + f * (b - a);
        }
        acc * r.step
    }

    /// Adjoint of [`Sheet::sample`]: add `val · step` times the sample weights into the sheet.
    pub(super) fn spread(&mut self, r: &SheetRay, val: f32) {
        let (qlo, qhi) = self.q_range();
        let w = val * r.step;
        for m in r.m0..=r.m1 {
            let (q, f) = r.z_neighbour(m, qlo, qhi);
            let idx = m * self.h + (q - qlo) as usize;
            let wf = w * f;
            self.data[idx] += w - wf;
            self.data[idx + 1] += wf;
        }
    }

    /// [`Sheet::sample`] eight planes at a time with AVX2 gathers (same positions and weights).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn sample_avx2(&self, r: &SheetRay) -> f32 {
        use std::arch::x86_64::*;
        let (qlo, qhi) = self.q_range();
        let h = self.h;
        // Lanes past m1 are clamped into the slack rows and masked out: every index below stays
        // under (m1 + LANES)·h ≤ data.len(), which also fits i32.
        assert!(
            (r.m1 + LANES) * h <= self.data.len() && self.data.len() <= i32::MAX as usize,
            "sheet too small for the ray"
        );
        let ptr = self.data.as_ptr();
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let lane_h = _mm256_mullo_epi32(lane, _mm256_set1_epi32(h as i32));
        let (z0, dz) = (_mm256_set1_ps(r.z0), _mm256_set1_ps(r.dz));
        let half = _mm256_set1_ps(0.5);
        let magic = _mm256_set1_ps(MAGIC);
        let magic_bits = _mm256_set1_epi32(MAGIC.to_bits() as i32);
        let (lo, hi) = (_mm256_set1_epi32(qlo), _mm256_set1_epi32(qhi));
        let end = _mm256_set1_epi32(r.m1 as i32 + 1);
        let mut acc = _mm256_setzero_ps();
        let mut m = r.m0;
        while m <= r.m1 {
            let mi = _mm256_add_epi32(_mm256_set1_epi32(m as i32), lane);
            // Same arithmetic as the scalar path: z = z0 + m·dz, q = floorish(z) clamped.
            let z = _mm256_add_ps(z0, _mm256_mul_ps(_mm256_cvtepi32_ps(mi), dz));
            let t = _mm256_add_ps(_mm256_sub_ps(z, half), magic);
            let q = _mm256_sub_epi32(_mm256_castps_si256(t), magic_bits);
            let q = _mm256_min_epi32(_mm256_max_epi32(q, lo), hi);
            let f = _mm256_sub_ps(z, _mm256_cvtepi32_ps(q));
            let idx = _mm256_add_epi32(
                _mm256_add_epi32(_mm256_set1_epi32((m * h) as i32), lane_h),
                _mm256_sub_epi32(q, lo),
            );
            // SAFETY: idx + 1 < (m1 + LANES)·h ≤ data.len() (asserted above) for every lane.
            let (a, b) = unsafe {
                (
                    _mm256_i32gather_ps::<4>(ptr, idx),
                    _mm256_i32gather_ps::<4>(ptr.add(1), idx),
                )
            };
            let v = _mm256_fmadd_ps(f, _mm256_sub_ps(b, a), a);
            let valid = _mm256_castsi256_ps(_mm256_cmpgt_epi32(end, mi));
            acc = _mm256_add_ps(acc, _mm256_and_ps(v, valid));
            m += LANES;
        }
        let s = _mm_add_ps(_mm256_castps256_ps128(acc), _mm256_extractf128_ps::<1>(acc));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        let s = _mm_add_ss(s, _mm_shuffle_ps::<1>(s, s));
        _mm_cvtss_f32(s) * r.step
    }
}

/// Volume offset (at z = `zlo`) and weight of the two horizontal neighbours of plane `m`;
/// neighbours outside `jr` (inclusive, within the grid) get weight 0 and offset 0.
#[inline(always)]
pub(super) fn plane_taps(
    layout: Layout,
    c: &ColumnWalk,
    m: usize,
    zlo: usize,
    jr: (usize, usize),
) -> [(usize, f32); 2] {
    let st = layout.stride;
    let plane = (c.lo as usize + m) * st[c.k] + zlo * st[2];
    c.corners(m).map(|(q, w)| {
        if q < jr.0 as i32 || q > jr.1 as i32 {
            (0, 0.0)
        } else {
            (plane + q as usize * st[c.j], w)
        }
    })
}
