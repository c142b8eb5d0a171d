//! Tile binning: which Gaussians touch which tile, and back.
//!
//! Each Gaussian covers a box of tiles (`lo..hi` per axis, 2D grids use one z tile). Binning is a
//! counting sort: `tile_start` / `tile_gaussians` list the Gaussians of every tile (the forward
//! pass walks a tile's list and owns the tile's pixels, so it needs no atomics), and
//! `gaussian_start` / `gaussian_isects` list every Gaussian's slots in that array (the backward
//! pass writes per-slot partial sums tile by tile, then gathers them per Gaussian).

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

    /// A counting sort in two parallel passes over chunks of Gaussians (count per tile, then
    /// write): chunk `c`'s entries of a tile follow those of chunks `< c`, so every tile lists
    /// its Gaussians in increasing order, as one serial pass would.
    fn build(tiles: [usize; 3], boxes: &[Option<TileBox>], gaussian_side: bool) -> Self {
        let n_tiles = tiles[0] * tiles[1] * tiles[2];
        let chunk = boxes
            .len()
            .div_ceil(4 * rayon::current_num_threads())
            .max(MIN_CHUNK);
        let chunks: Vec<&[Option<TileBox>]> = boxes.chunks(chunk).collect();
        // Per chunk: its count in every tile, then (rewritten in place) its first slot there.
        let mut cursors: Vec<Vec<usize>> = chunks
            .par_iter()
            .map(|c| {
                let mut n = vec![0usize; n_tiles];
                for b in c.iter().flatten() {
                    each_tile(tiles, b, |t| n[t] += 1);
                }
                n
            })
            .collect();
        let chunk_isects: Vec<usize> = cursors.iter().map(|n| n.iter().sum()).collect();
        let mut tile_start = vec![0usize; n_tiles + 1];
        for t in 0..n_tiles {
            let mut at = tile_start[t];
            for n in cursors.iter_mut() {
                (n[t], at) = (at, at + n[t]);
            }
            tile_start[t + 1] = at;
        }
        let total = tile_start[n_tiles];
        let mut tile_gaussians = vec![0u32; total];
        let (mut gaussian_start, mut gaussian_isects) = if gaussian_side {
            (vec![0usize; boxes.len() + 1], vec![0usize; total])
        } else {
            (Vec::new(), Vec::new())
        };
        // Every chunk's slice of the Gaussian side (its Gaussians' slots are contiguous there).
        let mut starts: Vec<&mut [usize]> = Vec::with_capacity(chunks.len());
        let mut isects: Vec<(usize, &mut [usize])> = Vec::with_capacity(chunks.len());
        if gaussian_side {
            starts.extend(gaussian_start[1..].chunks_mut(chunk));
            let (mut rest, mut offset) = (&mut gaussian_isects[..], 0);
            for &n in &chunk_isects {
                let (head, tail) = rest.split_at_mut(n);
                isects.push((offset, head));
                (rest, offset) = (tail, offset + n);
            }
        }
        let mut starts = starts.into_iter();
        let mut isects = isects.into_iter();
        let jobs: Vec<_> = cursors
            .iter_mut()
            .enumerate()
            .map(|(c, cur)| (c, cur, starts.next(), isects.next()))
            .collect();
        let out = SlotWriter(tile_gaussians.as_mut_ptr());
        jobs.into_par_iter()
            .for_each(|(c, cur, mut start, mut isect)| {
                let first = c * chunk;
                let mut written = 0;
                for (j, b) in chunks[c].iter().enumerate() {
                    if let Some(b) = b {
                        each_tile(tiles, b, |t| {
                            let slot = cur[t];
                            cur[t] += 1;
                            // SAFETY: `slot < total`, and the cursors hand out every slot exactly
                            // once over all chunks (disjoint ranges per (tile, chunk)), so no two
                            // writes alias.
                            unsafe { out.write(slot, (first + j) as u32) };
                            if let Some((_, isect)) = isect.as_mut() {
                                isect[written] = slot;
                            }
                            written += 1;
                        });
                    }
                    if let (Some(start), Some((offset, _))) = (start.as_mut(), isect.as_ref()) {
                        start[j] = offset + written;
                    }
                }
            });
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

    /// Many chunks: the parallel sort equals a serial counting sort (Gaussian order in every
    /// tile, slots pointing back).
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
        let bins = Bins::new(tiles, &boxes);
        for (t, list) in lists.iter().enumerate() {
            assert_eq!(
                &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]],
                &list[..]
            );
        }
        assert_eq!(bins.gaussian_start.len(), k + 1);
        let mut seen = vec![false; bins.isects()];
        for g in 0..k {
            let slots = &bins.gaussian_isects[bins.gaussian_start[g]..bins.gaussian_start[g + 1]];
            let n = boxes[g].map_or(0, |b| (0..3).map(|a| b.hi[a] - b.lo[a]).product::<usize>());
            assert_eq!(slots.len(), n);
            for &slot in slots {
                assert_eq!(bins.tile_gaussians[slot] as usize, g);
                assert!(!seen[slot]);
                seen[slot] = true;
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(
            Bins::tile_lists(tiles, &boxes).tile_gaussians,
            bins.tile_gaussians
        );
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
