//! Row-padded buffers: planes of rows stored `LANES` values apart beyond their width
//! (`[plane][row][width + LANES]`, the padding zero), so a lane block starting at any column of
//! a row lies inside the row. The forward passes' slabs and bands and the backward passes'
//! upstream gradients use this layout.

use rayon::prelude::*;

use super::lanes::LANES;

#[derive(Clone, Copy, Debug)]
pub(crate) struct PaddedRows {
    /// Values per row.
    width: usize,
    /// Rows per plane.
    rows: usize,
}

impl PaddedRows {
    pub(crate) fn new(width: usize, rows: usize) -> Self {
        Self { width, rows }
    }

    fn stride(&self) -> usize {
        self.width + LANES
    }

    fn plane_len(&self) -> usize {
        self.rows * self.stride()
    }

    /// Offset of column `x` of row `r` in plane `p`.
    #[inline(always)]
    pub(crate) fn at(&self, p: usize, r: usize, x: usize) -> usize {
        (p * self.rows + r) * self.stride() + x
    }

    /// `planes` planes of zeros.
    pub(crate) fn zeros(&self, planes: usize) -> Vec<f32> {
        vec![0.0; planes * self.plane_len()]
    }

    /// `src` (`[plane][row][width]`, unpadded, whole planes) in this layout.
    pub(crate) fn pad(&self, src: &[f32]) -> Vec<f32> {
        let mut out = self.zeros(src.len() / (self.rows * self.width).max(1));
        out.par_chunks_mut(self.stride())
            .zip(src.par_chunks(self.width))
            .for_each(|(dst, src)| dst[..self.width].copy_from_slice(src));
        out
    }

    /// Copy the rows of `buf` (this layout) into `dst` (`[plane][dst_rows][width]`, unpadded),
    /// plane by plane, from row `first` of each `dst` plane on.
    pub(crate) fn unpad_into(&self, buf: &[f32], dst: &mut [f32], dst_rows: usize, first: usize) {
        let w = self.width;
        for (p, plane) in dst.chunks_mut(dst_rows * w).enumerate() {
            for r in 0..self.rows {
                let src = self.at(p, r, 0);
                let o = (first + r) * w;
                plane[o..o + w].copy_from_slice(&buf[src..src + w]);
            }
        }
    }
}
