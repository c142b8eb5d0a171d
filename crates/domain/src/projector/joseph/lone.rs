//! The one ray of a detector column that has no other (a fan beam's single row): [`Sheet`]'s
//! arithmetic without the sheet.

use super::*;

/// The one ray of a detector column that has no other (a fan beam's single row): the sheet's
/// entries computed only where the ray reads them, each with [`Sheet::build`]'s arithmetic, and
/// summed as [`Sheet::sample`] / [`Sheet::sample_avx2`] sum them, so the result is bit for bit
/// the sheet's. For one ray, building the whole sheet cost several times the sampling.
pub(super) struct LoneRay<'a> {
    layout: Layout,
    column: &'a ColumnWalk,
    /// Horizontal index range with non-zero taps (inclusive), as for the sheet.
    jr: (usize, usize),
    /// The sheet's z-range `[zlo, zhi]` (its rows cover `[zlo − 1, zhi + 1]`).
    zlo: usize,
    zhi: usize,
}

impl<'a> LoneRay<'a> {
    /// The ray of `column` over `support`, with the sheet's ranges (as the column's sheet takes
    /// them: taps inside the support along `j`, z over the support's z-range).
    pub(super) fn new(layout: Layout, column: &'a ColumnWalk, support: &Support) -> Self {
        LoneRay {
            layout,
            column,
            jr: (support.0[column.j], support.1[column.j]),
            zlo: support.0[2],
            zhi: support.1[2],
        }
    }

    /// The volume offset (from a tap's, at z = `zlo`) of sheet row `row` (z = zlo − 1 + row);
    /// `None` for the two end rows, which the sheet keeps zero and never scatters.
    #[inline(always)]
    fn row_offset(&self, row: i32) -> Option<usize> {
        let z = row - 1;
        (z >= 0 && z as usize <= self.zhi - self.zlo).then(|| z as usize * self.layout.stride[2])
    }

    /// The sheet's entry at plane `m`, row `row`, as [`Sheet::build`] sums it.
    #[inline(always)]
    fn entry(&self, vol: &[f32], taps: &[(usize, f32); 2], row: i32) -> f32 {
        let Some(t) = self.row_offset(row) else {
            return 0.0;
        };
        if self.layout.stride[2] == 1 {
            let mut s = 0.0f32;
            for &(base, w) in taps.iter().filter(|t| t.1 != 0.0) {
                s += w * vol[base + t];
            }
            s
        } else {
            let [(b0, w0), (b1, w1)] = *taps;
            0.0 + (w0 * vol[b0 + t] + w1 * vol[b1 + t])
        }
    }

    /// The sheet row of the lower z neighbour of plane `m` and its weight, as the samplers find it.
    #[inline(always)]
    fn z_tap(&self, r: &SheetRay, m: usize) -> (i32, f32) {
        let qlo = self.zlo as i32 - 1;
        let (q, f) = r.z_neighbour(m, qlo, self.zhi as i32);
        (q - qlo, f)
    }

    /// The ray's linear sample in z at plane `m` (`fused`: as the vector sampler computes it).
    #[inline(always)]
    fn value(&self, vol: &[f32], r: &SheetRay, m: usize, fused: bool) -> f32 {
        let taps = plane_taps(self.layout, self.column, m, self.zlo, self.jr);
        let (row, f) = self.z_tap(r, m);
        let (a, b) = (self.entry(vol, &taps, row), self.entry(vol, &taps, row + 1));
        if fused {
            f.mul_add(b - a, a)
        } else {
            a + f * (b - a)
        }
    }

    /// [`Sheet::sample`] of the ray (`lanes`: [`Sheet::sample_avx2`]'s order of sums, eight
    /// planes per lane group, with fused multiply-adds).
    #[inline(always)]
    pub(super) fn sample(&self, vol: &[f32], r: &SheetRay, lanes: bool) -> f32 {
        if !lanes {
            let mut acc = 0.0f32;
            for m in r.m0..=r.m1 {
                acc += self.value(vol, r, m, false);
            }
            return acc * r.step;
        }
        let mut acc = [0.0f32; LANES];
        let mut m = r.m0;
        while m + LANES - 1 <= r.m1 {
            for (l, a) in acc.iter_mut().enumerate() {
                *a += self.value(vol, r, m + l, true);
            }
            m += LANES;
        }
        if m <= r.m1 {
            for (l, a) in acc.iter_mut().enumerate() {
                // Lanes past m1 add the masked +0.
                *a += if m + l <= r.m1 {
                    self.value(vol, r, m + l, true)
                } else {
                    0.0
                };
            }
        }
        let s = [
            acc[0] + acc[4],
            acc[1] + acc[5],
            acc[2] + acc[6],
            acc[3] + acc[7],
        ];
        ((s[0] + s[2]) + (s[1] + s[3])) * r.step
    }

    /// [`Sheet::spread`] of `val` along the ray followed by [`Sheet::scatter`] into `acc`: each
    /// plane's two z entries (the only non-zero ones) times its horizontal taps.
    #[inline(always)]
    pub(super) fn spread(&self, acc: &mut [f32], r: &SheetRay, val: f32) {
        let w = val * r.step;
        for m in r.m0..=r.m1 {
            let (row, f) = self.z_tap(r, m);
            let wf = w * f;
            let taps = plane_taps(self.layout, self.column, m, self.zlo, self.jr);
            for (row, v) in [(row, 0.0 + (w - wf)), (row + 1, 0.0 + wf)] {
                let Some(t) = self.row_offset(row) else {
                    continue;
                };
                for &(base, tw) in taps.iter().filter(|t| t.1 != 0.0) {
                    acc[base + t] += tw * v;
                }
            }
        }
    }
}
