//! SART, OS-SART and SIRT: one block-iterative algorithm with a block size.
//!
//! For each block (subset) B of views:
//!
//! `x ← P₊( x + λ · V_B⁻¹ ⊙ A_Bᵀ [ W_B ⊙ (b_B − A_B x) ] )`
//!
//! * `A` is the Joseph projector and `Aᵀ` its exact adjoint ([`Joseph`]);
//! * `W = 1 / (A·1)`: inverse ray length in the volume (row sums); rays shorter than half the
//!   smallest voxel size get `W = 0` (a grazing ray would otherwise get a huge weight);
//! * `V_B = A_Bᵀ·1`: the column sums over the block, `V⁻¹ = 0` for voxels no ray of B touches;
//! * `P₊` clips at 0 when `nonneg` is set; λ is multiplied by `lambda_decay` after every epoch.
//!
//! Block size 1 is SART (Andersen & Kak 1984), the number of views is SIRT, anything between is
//! OS-SART. Blocks are *interleaved* subsets (block s holds views s, s+m, s+2m, … for m blocks) so
//! every block spans the whole angular range; `order` visits the blocks in sequence or in a
//! seeded random permutation per epoch.

use super::par_zip;
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3, Axis, Zip};
use prism_domain::projector::Joseph;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Order in which blocks are visited within an epoch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Order {
    /// Block 0, 1, 2, … every epoch.
    Ordered,
    /// A fresh seeded random permutation of the blocks every epoch.
    #[default]
    Random,
}

/// Options of [`sart`].
#[derive(Clone, Debug, PartialEq)]
pub struct SartOptions {
    /// Epochs (full passes over all views), ≥ 1.
    pub iterations: usize,
    /// Views per block: 1 = SART, all = SIRT, between = OS-SART. Clamped to the view count.
    pub block_size: usize,
    /// Relaxation λ > 0 (convergent for λ < 2).
    pub lambda: f64,
    /// λ is multiplied by this after each epoch (1 = constant), in (0, 1].
    pub lambda_decay: f64,
    /// Clip negative values after each block update.
    pub nonneg: bool,
    pub order: Order,
    /// Seed of the random block order.
    pub seed: u64,
}

impl Default for SartOptions {
    fn default() -> Self {
        SartOptions {
            iterations: 10,
            block_size: 1,
            lambda: 1.0,
            lambda_decay: 1.0,
            nonneg: true,
            order: Order::Random,
            seed: 0,
        }
    }
}

impl SartOptions {
    /// Check ranges; errors name the field.
    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::invalid("iterations", "must be at least 1"));
        }
        if self.block_size == 0 {
            return Err(Error::invalid("block_size", "must be at least 1"));
        }
        // Block-iterative SART converges for relaxations in (0, 2) (Censor & Elfving); beyond,
        // each sweep overshoots and the result is noise, not a reconstruction.
        if !(self.lambda > 0.0 && self.lambda < 2.0) {
            return Err(Error::invalid(
                "lambda",
                format!(
                    "relaxation must lie in (0, 2), where the iteration converges (got {})",
                    self.lambda
                ),
            ));
        }
        if !(self.lambda_decay > 0.0 && self.lambda_decay <= 1.0) {
            return Err(Error::invalid(
                "lambda_decay",
                format!("must lie in (0, 1] (got {})", self.lambda_decay),
            ));
        }
        Ok(())
    }
}

/// Interleaved blocks of at most `block_size` views over `n` views.
pub fn blocks(n: usize, block_size: usize) -> Vec<Vec<usize>> {
    let m = block_count(n, block_size);
    (0..m).map(|s| (s..n).step_by(m).collect()).collect()
}

/// How many blocks [`blocks`] makes.
pub fn block_count(n: usize, block_size: usize) -> usize {
    n.div_ceil(block_size.clamp(1, n.max(1)))
}

/// Memory budget for caching the per-block column sums (bytes).
const V_CACHE_BYTES: usize = 512 << 20;

/// Whether the column sums of `blocks` blocks over `voxels` voxels are all kept (they fit in the
/// 512 MiB budget) rather than recomputed, one block at a time, at every visit.
pub fn caches_column_sums(blocks: usize, voxels: usize) -> bool {
    blocks.saturating_mul(voxels).saturating_mul(4) <= V_CACHE_BYTES
}

/// Reconstruct from `b` (`[view][row][col]`, all views of `a`'s geometry) starting at `x0`
/// (zeros when `None`); `progress(epoch)` is called after every epoch.
pub fn sart(
    a: &Joseph,
    b: ArrayView3<f32>,
    x0: Option<Array3<f32>>,
    opts: &SartOptions,
    progress: &mut dyn FnMut(usize),
) -> Result<Array3<f32>> {
    opts.validate()?;
    let n = a.views();
    let shape = a.projection_shape(n);
    prism_domain::error::ensure_shape("projections", b.shape(), &shape, "[views, rows, cols]")?;
    let grid = a.geometry().volume.clone();
    let mut x = match x0 {
        Some(x) if x.shape() == grid.shape_zyx() => x,
        Some(x) => {
            return Err(Error::invalid(
                "x0",
                format!(
                    "shape {:?} does not match the grid {:?}",
                    x.shape(),
                    grid.shape_zyx()
                ),
            ));
        }
        None => Array3::zeros(grid.shape_zyx()),
    };
    let all: Vec<usize> = (0..n).collect();
    // W: inverse ray lengths.
    let min_len = (grid.dx.min(grid.dy).min(grid.dz) / 2.0) as f32;
    let w = a
        .ray_lengths(&all)?
        .mapv(|l| if l > min_len { 1.0 / l } else { 0.0 });
    let blocks = blocks(n, opts.block_size);
    let column_sums = |blk: &[usize]| -> Result<Array3<f32>> {
        let ones = Array3::<f32>::ones(a.projection_shape(blk.len()));
        Ok(a.adjoint_views(ones.view(), blk)?
            .mapv(|v| if v > 1e-6 { 1.0 / v } else { 0.0 }))
    };
    let cache = caches_column_sums(blocks.len(), grid.len());
    let v_cached: Vec<Array3<f32>> = if cache {
        blocks
            .iter()
            .map(|blk| column_sums(blk))
            .collect::<Result<_>>()?
    } else {
        Vec::new()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let mut lambda = opts.lambda as f32;
    let mut visit: Vec<usize> = (0..blocks.len()).collect();
    for epoch in 0..opts.iterations {
        if opts.order == Order::Random {
            visit.shuffle(&mut rng);
        }
        for &bi in &visit {
            let blk = &blocks[bi];
            let mut r = a.forward_views(x.view(), blk)?;
            for (k, &view) in blk.iter().enumerate() {
                Zip::from(r.index_axis_mut(Axis(0), k))
                    .and(b.index_axis(Axis(0), view))
                    .and(w.index_axis(Axis(0), view))
                    .for_each(|r, &b, &w| *r = w * (b - *r));
            }
            let upd = a.adjoint_views(r.view(), blk)?;
            let v_fresh;
            let v = if cache {
                &v_cached[bi]
            } else {
                v_fresh = column_sums(blk)?;
                &v_fresh
            };
            let nonneg = opts.nonneg;
            let mut step = upd;
            par_zip(&mut step, v, |u, v| lambda * u * v);
            par_zip(
                &mut x,
                &step,
                |x, s| if nonneg { (x + s).max(0.0) } else { x + s },
            );
        }
        lambda *= opts.lambda_decay as f32;
        progress(epoch + 1);
    }
    Ok(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_are_interleaved_and_cover_every_view_once() {
        assert_eq!(
            blocks(5, 1),
            vec![vec![0], vec![1], vec![2], vec![3], vec![4]]
        );
        assert_eq!(blocks(5, 5), vec![vec![0, 1, 2, 3, 4]]);
        assert_eq!(blocks(7, 3), vec![vec![0, 3, 6], vec![1, 4], vec![2, 5]]);
        assert_eq!(blocks(4, 100), vec![vec![0, 1, 2, 3]]);
    }

    #[test]
    fn bad_options_name_their_field() {
        let base = SartOptions::default();
        for (opts, field) in [
            (
                SartOptions {
                    iterations: 0,
                    ..base.clone()
                },
                "iterations",
            ),
            (
                SartOptions {
                    block_size: 0,
                    ..base.clone()
                },
                "block_size",
            ),
            (
                SartOptions {
                    lambda: 0.0,
                    ..base.clone()
                },
                "lambda",
            ),
            (
                SartOptions {
                    lambda: -1.0,
                    ..base.clone()
                },
                "lambda",
            ),
            (
                SartOptions {
                    lambda: f64::NAN,
                    ..base.clone()
                },
                "lambda",
            ),
            (
                SartOptions {
                    lambda_decay: 1.5,
                    ..base.clone()
                },
                "lambda_decay",
            ),
        ] {
            let e = opts.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        }
    }
}
