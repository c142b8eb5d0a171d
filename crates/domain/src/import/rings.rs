//! Ring suppression. A detector pixel whose response differs from its neighbours' (gain drift, a
//! scintillator defect, dust) adds the same error to every view: a stripe in each sinogram
//! (`[views][cols]` of one detector row), and a ring about the rotation axis in the volume.
//!
//! The filter is Vo, Atwood & Drakopoulos' sorting-based stripe removal (Opt. Express 26, 28396,
//! 2018, algorithm 3): in each sinogram every column is sorted along the views, each row of the
//! sorted sinogram is median-filtered across `size` neighbouring columns, and the values are put
//! back in their views. Sorting lines up the distributions of neighbouring columns, so a column
//! whose whole distribution is shifted (a full or partial stripe) is pulled to its neighbours'
//! while edges of the object, which move across columns from view to view, are left alone. It
//! removes stripes narrower than about `size / 2` columns. Applied to the transmission `I / I₀`
//! before the log for counts, to the line integrals as given otherwise.

use crate::{Error, Result};
use ndarray::{Array2, Array3, Axis};
use rayon::prelude::*;
use serde::Deserialize;

/// `rings:` of an import config.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RingConfig {
    #[serde(default)]
    pub method: RingMethod,
    /// Median window across detector columns, odd (default 21, as Vo et al. and TomoPy).
    #[serde(default = "default_size")]
    pub size: usize,
}

/// How stripes are removed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RingMethod {
    /// Sorting-based stripe removal (module docs).
    #[default]
    Sorting,
}

fn default_size() -> usize {
    21
}

/// Scratch per sinogram value while a row is filtered: its copy, the sorted copy (f32 each) and
/// the views' order (usize), and the filtered row held until it is written back.
pub const SCRATCH_BYTES: usize = 4 + 4 + 8 + 4;

/// Detector rows filtered at once (in parallel).
pub fn batch_rows() -> usize {
    2 * rayon::current_num_threads().max(1)
}

impl RingConfig {
    /// The window must be odd, at least 3 and at most the detector's `cols`.
    pub fn validate(&self, cols: usize) -> Result<()> {
        if self.size < 3 || self.size.is_multiple_of(2) || self.size > cols {
            return Err(Error::invalid(
                "rings.size",
                format!(
                    "must be an odd number of columns between 3 and the detector's {cols}, got {}",
                    self.size
                ),
            ));
        }
        Ok(())
    }

    /// Remove stripes from every detector row of `stack` (`[views][rows][cols]`), in place. Rows
    /// go in parallel, a few per thread at a time, so the scratch (about 16 bytes per value of
    /// a sinogram) stays small beside the stack.
    pub fn apply(&self, stack: &mut Array3<f32>) -> Result<()> {
        self.validate(stack.len_of(Axis(2)))?;
        let rows = stack.len_of(Axis(1));
        let batch = batch_rows();
        for first in (0..rows).step_by(batch) {
            let last = (first + batch).min(rows);
            let filtered: Vec<Array2<f32>> = (first..last)
                .into_par_iter()
                .map(|r| {
                    let mut sino = stack.index_axis(Axis(1), r).to_owned();
                    match self.method {
                        RingMethod::Sorting => remove_stripes_by_sorting(&mut sino, self.size),
                    }
                    sino
                })
                .collect();
            for (r, sino) in (first..last).zip(filtered) {
                stack.index_axis_mut(Axis(1), r).assign(&sino);
            }
        }
        Ok(())
    }
}

/// Sorting-based stripe removal on one sinogram `[views][cols]` with an odd window `size`
/// (columns beyond the edges mirrored: `… c1 c0 | c0 c1 …`).
pub fn remove_stripes_by_sorting(sino: &mut Array2<f32>, size: usize) {
    let (views, cols) = sino.dim();
    if views == 0 || cols == 0 {
        return;
    }
    let half = size / 2;
    // Each column sorted along the views: `sorted[k][c]` is the k-th smallest of column c, found
    // at view `order[k][c]`.
    let mut sorted = Array2::<f32>::zeros((views, cols));
    let mut order = Array2::<usize>::zeros((views, cols));
    let mut column: Vec<(f32, usize)> = Vec::with_capacity(views);
    for c in 0..cols {
        column.clear();
        column.extend((0..views).map(|v| (sino[[v, c]], v)));
        column.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for (k, &(x, v)) in column.iter().enumerate() {
            sorted[[k, c]] = x;
            order[[k, c]] = v;
        }
    }
    let mirror = |j: isize| -> usize {
        let n = cols as isize;
        let j = if j < 0 { -j - 1 } else { j };
        let j = if j >= n { 2 * n - j - 1 } else { j };
        j.clamp(0, n - 1) as usize
    };
    let mut window = vec![0.0f32; size];
    for k in 0..views {
        let row = sorted.row(k);
        for c in 0..cols {
            for (i, w) in window.iter_mut().enumerate() {
                *w = row[mirror(c as isize + i as isize - half as isize)];
            }
            let (_, median, _) = window.select_nth_unstable_by(half, f32::total_cmp);
            sino[[order[[k, c]], c]] = *median;
        }
    }
}
