//! Tile binning: which Gaussians touch which tile, and back.
//!
//! Each Gaussian covers a box of tiles (`lo..hi` per axis, 2D grids use one z tile). Binning is a
//! counting sort: `tile_start` / `tile_gaussians` list the Gaussians of every tile (the forward
//! pass walks a tile's list and owns the tile's pixels, so it needs no atomics), and
//! `gaussian_start` / `gaussian_isects` list every Gaussian's slots in that array (the backward
//! pass writes per-slot partial sums tile by tile, then gathers them per Gaussian).

/// A box of tiles, `lo` inclusive, `hi` exclusive, per axis `[x, y, z]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileBox {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
}

/// The tile ↔ Gaussian incidence of one pass.
#[derive(Debug, Default)]
pub struct Bins {
    /// Tile `t`'s Gaussians are `tile_gaussians[tile_start[t]..tile_start[t + 1]]`.
    pub tile_start: Vec<usize>,
    pub tile_gaussians: Vec<u32>,
    /// Gaussian `g`'s slots in `tile_gaussians` are `gaussian_isects[gaussian_start[g]..gaussian_start[g + 1]]`
    /// (both empty when built by [`Bins::tile_lists`]).
    pub gaussian_start: Vec<usize>,
    pub gaussian_isects: Vec<usize>,
}

impl Bins {
    /// Bin Gaussians into a `tiles = [tx, ty, tz]` grid; tile index `(z·ty + y)·tx + x`.
    pub fn new(tiles: [usize; 3], boxes: &[Option<TileBox>]) -> Self {
        Self::build(tiles, boxes, true)
    }

    /// [`Bins::new`] without the Gaussian → slot side (`gaussian_start` and `gaussian_isects`
    /// left empty): all a forward pass reads, at about half the serial cost.
    pub fn tile_lists(tiles: [usize; 3], boxes: &[Option<TileBox>]) -> Self {
        Self::build(tiles, boxes, false)
    }

    fn build(tiles: [usize; 3], boxes: &[Option<TileBox>], gaussian_side: bool) -> Self {
        let n_tiles = tiles[0] * tiles[1] * tiles[2];
        let mut tile_count = vec![0usize; n_tiles + 1];
        for b in boxes.iter().flatten() {
            each_tile(tiles, b, |t| tile_count[t + 1] += 1);
        }
        for t in 0..n_tiles {
            tile_count[t + 1] += tile_count[t];
        }
        let total = tile_count[n_tiles];
        let tile_start = tile_count;
        let mut cursor = tile_start.clone();
        let mut tile_gaussians = vec![0u32; total];
        let (mut gaussian_start, mut gaussian_isects) = (Vec::new(), Vec::new());
        if gaussian_side {
            gaussian_start.reserve(boxes.len() + 1);
            gaussian_start.push(0);
            gaussian_isects.reserve(total);
        }
        for (g, b) in boxes.iter().enumerate() {
            if let Some(b) = b {
                each_tile(tiles, b, |t| {
                    let slot = cursor[t];
                    cursor[t] += 1;
                    tile_gaussians[slot] = g as u32;
                    if gaussian_side {
                        gaussian_isects.push(slot);
                    }
                });
            }
            if gaussian_side {
                gaussian_start.push(gaussian_isects.len());
            }
        }
        Self {
            tile_start,
            tile_gaussians,
            gaussian_start,
            gaussian_isects,
        }
    }

    pub fn tiles(&self) -> usize {
        self.tile_start.len() - 1
    }

    /// Total number of (tile, Gaussian) pairs.
    pub fn isects(&self) -> usize {
        self.tile_gaussians.len()
    }

    /// Split a per-slot buffer (`stride` values per slot) into one mutable slice per tile.
    pub fn split_per_tile<'a, T>(&self, mut buf: &'a mut [T], stride: usize) -> Vec<&'a mut [T]> {
        let mut out = Vec::with_capacity(self.tiles());
        for t in 0..self.tiles() {
            let n = (self.tile_start[t + 1] - self.tile_start[t]) * stride;
            let (head, tail) = buf.split_at_mut(n);
            out.push(head);
            buf = tail;
        }
        out
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
    fn binning_round_trips() {
        let boxes = vec![
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
        let bins = Bins::new([3, 2, 1], &boxes);
        assert_eq!(bins.isects(), 2 + 4);
        // Tile 1 (x=1, y=0) holds Gaussians 0 and 2.
        assert_eq!(
            &bins.tile_gaussians[bins.tile_start[1]..bins.tile_start[2]],
            &[0, 2]
        );
        // Every Gaussian's slots point back at it.
        for g in 0..3 {
            for &slot in &bins.gaussian_isects[bins.gaussian_start[g]..bins.gaussian_start[g + 1]] {
                assert_eq!(bins.tile_gaussians[slot] as usize, g);
            }
        }
        assert_eq!(bins.gaussian_start, vec![0, 2, 2, 6]);
        let lists = Bins::tile_lists([3, 2, 1], &boxes);
        assert_eq!(lists.tile_start, bins.tile_start);
        assert_eq!(lists.tile_gaussians, bins.tile_gaussians);
        assert!(lists.gaussian_start.is_empty() && lists.gaussian_isects.is_empty());
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
