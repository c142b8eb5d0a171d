//! Tile binning: which Gaussians touch which tile.
//!
//! Each Gaussian covers a box of tiles (`lo..hi` per axis; the forward passes use one axis: bands
//! of detector rows, slabs of z-slices). Binning is one parallel pass over chunks of Gaussians:
//! each chunk lists, per tile, an item of each of its Gaussians there, in index order, and a
//! tile's list is its chunks' lists in chunk order, so every tile lists its Gaussians in index
//! order (a forward pass walks a tile's list and owns the tile's pixels or voxels, so it needs
//! no atomics). The item is what the pass reads of the Gaussian: its index, or its splat with
//! the index, so a tile's splats lie together in the order the pass reads them.

use rayon::prelude::*;

/// Gaussians per binning task, at least.
const MIN_CHUNK: usize = 4096;

/// A box of tiles, `lo` inclusive, `hi` exclusive, per axis `[x, y, z]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileBox {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
}

/// An item of every Gaussian of every tile, for one pass: per chunk of Gaussians, per tile.
#[derive(Debug, Default)]
pub struct Bins<T = u32> {
    chunks: Vec<Vec<Vec<T>>>,
    tiles: usize,
}

impl<T: Copy + Send + Sync> Bins<T> {
    /// Bin the `n` Gaussians whose boxes and items `entry(i)` gives (`None`: in no tile) into
    /// a `tiles = [tx, ty, tz]` grid; tile index `(z·ty + y)·tx + x`. Each entry is computed
    /// once, in parallel; nothing is kept per Gaussian.
    pub fn from_fn(
        tiles: [usize; 3],
        n: usize,
        entry: impl Fn(usize) -> Option<(TileBox, T)> + Sync,
    ) -> Self {
        let n_tiles = tiles[0] * tiles[1] * tiles[2];
        let chunk = n.div_ceil(4 * rayon::current_num_threads()).max(MIN_CHUNK);
        let chunks = (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let range = c * chunk..((c + 1) * chunk).min(n);
                // Room for each Gaussian in about two tiles, spread evenly.
                let room = 2 * range.len() / n_tiles.max(1) + 16;
                let mut lists: Vec<Vec<T>> =
                    (0..n_tiles).map(|_| Vec::with_capacity(room)).collect();
                for (b, item) in range.filter_map(&entry) {
                    each_tile(tiles, &b, |t| lists[t].push(item));
                }
                lists
            })
            .collect();
        Self {
            chunks,
            tiles: n_tiles,
        }
    }

    pub fn tiles(&self) -> usize {
        self.tiles
    }

    /// Tile `t`'s items, in Gaussian index order (its chunks' lists in turn).
    pub fn of(&self, t: usize) -> impl Iterator<Item = &T> {
        self.chunks.iter().flat_map(move |lists| &lists[t])
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
        let bins = Bins::from_fn([3, 2, 1], boxes.len(), |i| boxes[i].map(|b| (b, i as u32)));
        let listed = |t: usize| bins.of(t).copied().collect::<Vec<u32>>();
        assert_eq!((0..6).map(|t| listed(t).len()).sum::<usize>(), 2 + 4);
        // Tile 1 (x=1, y=0) holds Gaussians 0 and 2.
        assert_eq!(listed(1), [0, 2]);
        assert_eq!(listed(0), [0]);
        assert_eq!(listed(3), [] as [u32; 0]);
        assert_eq!(listed(5), [2]);
    }

    /// Many chunks: the parallel binning equals a serial one (Gaussian order in every tile).
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
        let bins = Bins::from_fn(tiles, boxes.len(), |i| boxes[i].map(|b| (b, i as u32)));
        assert_eq!(bins.tiles(), n_tiles);
        for (t, list) in lists.iter().enumerate() {
            assert_eq!(bins.of(t).copied().collect::<Vec<u32>>(), *list);
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
