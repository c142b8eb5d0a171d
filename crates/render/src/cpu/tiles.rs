//! Tile binning: which Gaussians touch which tile.
//!
//! Each Gaussian covers a box of tiles (`lo..hi` per axis; the forward passes use one axis: bands
//! of detector rows, slabs of z-slices). Binning is a counting sort: `tile_start` /
//! `tile_gaussians` list the Gaussians of every tile in index order (a forward pass walks a
//! tile's list and owns the tile's pixels or voxels, so it needs no atomics).

use rayon::prelude::*;

/// Gaussians per binning task, at least.
const MIN_CHUNK: usize = 4096;

/// Writes Gaussian indices into distinct slots of `tile_gaussians` from several tasks.
struct SlotWriter(*mut u32);

// SAFETY: tasks write disjoint slots (see `Bins::build`) and the buffer outlives them.
unsafe impl Send for SlotWriter {}
unsafe impl Sync for SlotWriter {}

impl SlotWriter {
    /// # Safety
    /// `slot` is in bounds and written by no other task.
    #[inline(always)]
    unsafe fn write(&self, slot: usize, g: u32) {
        // SAFETY: the caller's contract.
        unsafe { self.0.add(slot).write(g) }
    }
}

/// A box of tiles, `lo` inclusive, `hi` exclusive, per axis `[x, y, z]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileBox {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
}

/// The Gaussians of every tile, for one pass.
#[derive(Debug, Default)]
pub struct Bins {
    /// Tile `t`'s Gaussians are `tile_gaussians[tile_start[t]..tile_start[t + 1]]`.
    pub tile_start: Vec<usize>,
    pub tile_gaussians: Vec<u32>,
}

impl Bins {
    /// Bin the `n` Gaussians whose boxes `box_of(i)` gives (`None`: in no tile) into a
    /// `tiles = [tx, ty, tz]` grid; tile index `(z·ty + y)·tx + x`. The boxes are computed as
    /// needed (once per pass, in parallel), not kept in an array of one per Gaussian.
    ///
    /// A counting sort in two parallel passes over chunks of Gaussians (count per tile, then
    /// write): chunk `c`'s entries of a tile follow those of chunks `< c`, so every tile lists
    /// its Gaussians in increasing order, as one serial pass would.
    pub fn from_fn(
        tiles: [usize; 3],
        n: usize,
        box_of: impl Fn(usize) -> Option<TileBox> + Sync,
    ) -> Self {
        let n_tiles = tiles[0] * tiles[1] * tiles[2];
        let chunk = n.div_ceil(4 * rayon::current_num_threads()).max(MIN_CHUNK);
        let chunks: Vec<std::ops::Range<usize>> = (0..n.div_ceil(chunk))
            .map(|c| c * chunk..((c + 1) * chunk).min(n))
            .collect();
        // Per chunk: its count in every tile, then (rewritten in place) its first slot there.
        let mut cursors: Vec<Vec<usize>> = chunks
            .par_iter()
            .map(|c| {
                let mut n = vec![0usize; n_tiles];
                for b in c.clone().filter_map(&box_of) {
                    each_tile(tiles, &b, |t| n[t] += 1);
                }
                n
            })
            .collect();
        let mut tile_start = vec![0usize; n_tiles + 1];
        for t in 0..n_tiles {
            let mut at = tile_start[t];
            for n in cursors.iter_mut() {
                (n[t], at) = (at, at + n[t]);
            }
            tile_start[t + 1] = at;
        }
        let mut tile_gaussians = vec![0u32; tile_start[n_tiles]];
        let out = SlotWriter(tile_gaussians.as_mut_ptr());
        cursors.par_iter_mut().enumerate().for_each(|(c, cur)| {
            for i in chunks[c].clone() {
                if let Some(b) = box_of(i) {
                    each_tile(tiles, &b, |t| {
                        let slot = cur[t];
                        cur[t] += 1;
                        // SAFETY: `slot < total`, and the cursors hand out every slot exactly
                        // once over all chunks (disjoint ranges per (tile, chunk)), so no two
                        // writes alias.
                        unsafe { out.write(slot, i as u32) };
                    });
                }
            }
        });
        Self {
            tile_start,
            tile_gaussians,
        }
    }

    pub fn tiles(&self) -> usize {
        self.tile_start.len() - 1
    }

    /// Tile `t`'s Gaussians, in index order.
    pub fn of(&self, t: usize) -> &[u32] {
        &self.tile_gaussians[self.tile_start[t]..self.tile_start[t + 1]]
    }
}

/// Call `f(tile index)` for every tile of `b` in a `tiles = [tx, ty, tz]` grid (x fastest).
#[inline(always)]
fn each_tile(tiles: [usize; 3], b: &TileBox, mut f: impl FnMut(usize)) {
    for z in b.lo[2]..b.hi[2] {
        for y in b.lo[1]..b.hi[1] {
            let row = (z * tiles[1] + y) * tiles[0];
            for x in b.lo[0]..b.hi[0] {
                f(row + x);
            }
        }
    }
}

/// Tile range `[lo, hi)` of the pixel/voxel index interval `[first, last]` (inclusive), for a
/// grid of `n` cells in tiles of `size`; `None` if the interval misses the grid.
#[inline]
pub fn tile_span(
    first: f64,
    last: f64,
    n: usize,
    size: usize,
) -> Option<(usize, usize, usize, usize)> {
    // Pixel/voxel index range, clamped to the grid (f64 comparisons tolerate ±∞ and huge values).
    let lo = first.ceil().max(0.0);
    let hi = last.floor().min(n as f64 - 1.0);
    if lo.partial_cmp(&hi) == Some(std::cmp::Ordering::Greater) || lo.is_nan() || hi.is_nan() {
        return None;
    }
    let (lo, hi) = (lo as usize, hi as usize);
    Some((lo, hi + 1, lo / size, hi / size + 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binning_lists_each_tiles_gaussians() {
        let boxes = [
            Some(TileBox {
                lo: [0, 0, 0],
                hi: [2, 1, 1],
            }),
            None,
            Some(TileBox {
                lo: [1, 0, 0],
                hi: [3, 2, 1],
            }),
        ];
        let bins = Bins::from_fn([3, 2, 1], boxes.len(), |i| boxes[i]);
        assert_eq!(bins.tile_gaussians.len(), 2 + 4);
        // Tile 1 (x=1, y=0) holds Gaussians 0 and 2.
        assert_eq!(bins.of(1), &[0, 2]);
        assert_eq!(bins.of(0), &[0]);
        assert_eq!(bins.of(3), &[] as &[u32]);
        assert_eq!(bins.of(5), &[2]);
    }

    /// Many chunks: the parallel sort equals a serial counting sort (Gaussian order in every
    /// tile).
    #[test]
    fn parallel_binning_matches_a_serial_sort() {
        let tiles = [5, 4, 3];
        let k = 5 * MIN_CHUNK + 123;
        let boxes: Vec<Option<TileBox>> = (0..k)
            .map(|g| {
                let h = (g as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32;
                (!h.is_multiple_of(7)).then(|| {
                    let lo = [h as usize % 5, (h >> 3) as usize % 4, (h >> 5) as usize % 3];
                    TileBox {
                        lo,
                        hi: [
                            (lo[0] + 1 + (h >> 7) as usize % 2).min(5),
                            (lo[1] + 1 + (h >> 9) as usize % 3).min(4),
                            (lo[2] + 1).min(3),
                        ],
                    }
                })
            })
            .collect();
        let n_tiles = 5 * 4 * 3;
        let mut lists = vec![Vec::new(); n_tiles];
        for (g, b) in boxes.iter().enumerate() {
            if let Some(b) = b {
                each_tile(tiles, b, |t| lists[t].push(g as u32));
            }
        }
        let bins = Bins::from_fn(tiles, boxes.len(), |i| boxes[i]);
        assert_eq!(bins.tiles(), n_tiles);
        for (t, list) in lists.iter().enumerate() {
            assert_eq!(bins.of(t), &list[..]);
        }
    }

    #[test]
    fn spans_clamp_and_reject() {
        assert_eq!(tile_span(-3.2, 2.5, 10, 4), Some((0, 3, 0, 1)));
        assert_eq!(tile_span(3.5, 100.0, 10, 4), Some((4, 10, 1, 3)));
        assert_eq!(tile_span(10.5, 12.0, 10, 4), None);
        assert_eq!(
            tile_span(f64::NEG_INFINITY, f64::INFINITY, 1, 16),
            Some((0, 1, 0, 1))
        );
        assert_eq!(tile_span(2.2, 2.8, 10, 4), None);
    }
}
