//! The multiresolution hash grid (Müller et al. 2022, as NAF uses it): its configuration and
//! the table layout every kernel (CPU and CubeCL) indexes the same way.
//!
//! Conventions. Points are in the unit cube `[0, 1]³` (callers map their volume box onto it;
//! values outside are clamped, non-finite coordinates read as 0). Level `ℓ` has the scale
//! `s_ℓ = base · growth^ℓ − 1`; a point `x` sits at the grid position `x · s_ℓ + ½`, whose cell
//! corners are `⌊x · s_ℓ + ½⌋ + {0, 1}` per axis, trilinearly weighted. A level with
//! `n_ℓ = ⌊s_ℓ + ½⌋ + 2` vertices per axis is stored densely when `n_ℓ³` fits the table size
//! `2^log2_table_size` (index `i + n(j + n k)`), and hashed otherwise (index
//! `(i ⊕ 19349663·j ⊕ 83492791·k) mod 2^log2_table_size`, wrapping u32 products). The table is
//! one `[rows, F]` tensor: level ℓ's entries are rows `offset_ℓ .. offset_ℓ + size_ℓ`. The
//! encoding of a point is `[L · F]`, level-major.

use crate::error::{FieldError, Result};
use serde::{Deserialize, Serialize};

/// The hash primes of the y and z coordinates (x's is 1).
pub const PRIMES: [u32; 2] = [19_349_663, 83_492_791];

/// The encoder's hyper-parameters (NAF's defaults).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HashGridConfig {
    /// Number of resolution levels L.
    pub levels: usize,
    /// Features per level F.
    pub features: usize,
    /// Vertices per axis of the coarsest level (its scale is `base_resolution − 1`).
    pub base_resolution: usize,
    /// Scale factor between consecutive levels.
    pub growth: f64,
    /// log₂ of the most entries one level's table holds.
    pub log2_table_size: u32,
}

impl Default for HashGridConfig {
    fn default() -> Self {
        HashGridConfig {
            levels: 16,
            features: 2,
            base_resolution: 16,
            growth: 2.0,
            log2_table_size: 19,
        }
    }
}

impl HashGridConfig {
    /// Check every field; errors name it (under `field`, e.g. `hash_grid`).
    pub fn validate(&self, field: &str) -> Result<()> {
        let bad =
            |name: &str, msg: String| Err(FieldError::invalid(format!("{field}.{name}"), msg));
        if !(1..=32).contains(&self.levels) {
            return bad("levels", format!("must be in 1..=32, got {}", self.levels));
        }
        if !(1..=8).contains(&self.features) {
            return bad(
                "features",
                format!("must be in 1..=8, got {}", self.features),
            );
        }
        if self.base_resolution < 2 {
            return bad(
                "base_resolution",
                format!("must be at least 2, got {}", self.base_resolution),
            );
        }
        if !(self.growth.is_finite() && self.growth >= 1.0) {
            return bad(
                "growth",
                format!("must be finite and ≥ 1, got {}", self.growth),
            );
        }
        if !(4..=24).contains(&self.log2_table_size) {
            return bad(
                "log2_table_size",
                format!("must be in 4..=24, got {}", self.log2_table_size),
            );
        }
        let finest = self.base_resolution as f64 * self.growth.powi(self.levels as i32 - 1);
        if finest > 1.0e6 {
            return bad(
                "growth",
                format!(
                    "the finest level's resolution {finest:.3e} exceeds 10⁶ (fewer levels or a smaller growth)"
                ),
            );
        }
        Ok(())
    }

    /// The table layout (call [`HashGridConfig::validate`] first).
    pub fn layout(&self) -> HashGrid {
        let cap = 1u64 << self.log2_table_size;
        let mut offset = 0u64;
        let levels = (0..self.levels)
            .map(|l| {
                let scale = self.base_resolution as f64 * self.growth.powi(l as i32) - 1.0;
                let res = (scale + 0.5).floor() as u64 + 2;
                let dense = res * res * res <= cap;
                let size = if dense { res * res * res } else { cap };
                let level = Level {
                    offset: offset as u32,
                    size: size as u32,
                    res: res as u32,
                    scale: scale as f32,
                    dense,
                };
                offset += size;
                level
            })
            .collect();
        HashGrid {
            levels,
            features: self.features,
        }
    }
}

/// One level of the table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Level {
    /// First table row of the level.
    pub offset: u32,
    /// Table rows of the level (`res³` dense, `2^log2_table_size` hashed).
    pub size: u32,
    /// Vertices per axis.
    pub res: u32,
    /// `base · growth^ℓ − 1`.
    pub scale: f32,
    /// Whether vertices are indexed densely (else hashed).
    pub dense: bool,
}

impl Level {
    /// The table row (relative to the level's offset) of vertex `(i, j, k)`.
    #[inline]
    pub fn index(&self, i: u32, j: u32, k: u32) -> u32 {
        if self.dense {
            i + self.res * (j + self.res * k)
        } else {
            (i ^ j.wrapping_mul(PRIMES[0]) ^ k.wrapping_mul(PRIMES[1])) & (self.size - 1)
        }
    }

    /// The 8 corner rows (absolute) and trilinear weights of point `p` (unit cube), corner `c`
    /// taking `+1` on axis `a` when bit `a` of `c` is set.
    ///
    /// The per-axis cell, weights and index terms are computed once and combined per corner (a
    /// weight is `(w_x · w_y) · w_z`, the product in axis order).
    #[inline(always)]
    pub fn corners(&self, p: [f32; 3]) -> ([u32; 8], [f32; 8]) {
        let mut cell = [0u32; 3];
        let mut frac = [0f32; 3];
        for a in 0..3 {
            let x = if p[a].is_finite() {
                p[a].clamp(0.0, 1.0)
            } else {
                0.0
            };
            // pos ≥ 0.5, so truncation is its floor (and needs no call to libm's floorf).
            let pos = x * self.scale + 0.5;
            // The top vertex is res − 1: keep the cell's upper corner inside.
            let c = (pos as u32).min(self.res - 2);
            cell[a] = c;
            frac[a] = pos - c as f32;
        }
        let w = [0, 1, 2].map(|a| [1.0 - frac[a], frac[a]]);
        // Each axis's contribution to the row index, at the cell's lower and upper vertex.
        let terms = if self.dense {
            let (r, c) = (self.res, cell);
            [
                [c[0], c[0] + 1],
                [r * c[1], r * (c[1] + 1)],
                [r * r * c[2], r * r * (c[2] + 1)],
            ]
        } else {
            let c = cell;
            [
                [c[0], c[0] + 1],
                [
                    c[1].wrapping_mul(PRIMES[0]),
                    (c[1] + 1).wrapping_mul(PRIMES[0]),
                ],
                [
                    c[2].wrapping_mul(PRIMES[1]),
                    (c[2] + 1).wrapping_mul(PRIMES[1]),
                ],
            ]
        };
        let mut rows = [0u32; 8];
        let mut weights = [0f32; 8];
        for c in 0..8 {
            let (x, y, z) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let index = if self.dense {
                terms[0][x] + terms[1][y] + terms[2][z]
            } else {
                (terms[0][x] ^ terms[1][y] ^ terms[2][z]) & (self.size - 1)
            };
            rows[c] = self.offset + index;
            weights[c] = w[0][x] * w[1][y] * w[2][z];
        }
        (rows, weights)
    }
}

/// The table layout of a [`HashGridConfig`]: what the encoder op takes.
#[derive(Clone, Debug, PartialEq)]
pub struct HashGrid {
    pub levels: Vec<Level>,
    /// Features per level F.
    pub features: usize,
}

impl HashGrid {
    /// Rows of the whole table.
    pub fn rows(&self) -> usize {
        self.levels
            .last()
            .map_or(0, |l| l.offset as usize + l.size as usize)
    }

    /// Width of a point's encoding, `L · F`.
    pub fn width(&self) -> usize {
        self.levels.len() * self.features
    }

    /// Trainable parameters of the table.
    pub fn parameters(&self) -> usize {
        self.rows() * self.features
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_follows_the_papers_sizes() {
        let g = HashGridConfig::default().layout();
        assert_eq!(g.levels.len(), 16);
        // Level 0: scale 15, 17 vertices per axis, dense.
        assert_eq!((g.levels[0].res, g.levels[0].dense), (17, true));
        assert_eq!(g.levels[0].size, 17 * 17 * 17);
        // 16·2^ℓ+1 vertices: 65³ = 274 625 ≤ 2^19 is dense, 129³ is not.
        assert!(g.levels[2].dense && !g.levels[3].dense);
        assert_eq!(g.levels[3].size, 1 << 19);
        assert_eq!(g.levels[1].offset, 17 * 17 * 17);
        assert_eq!(g.width(), 32);
        assert_eq!(
            g.rows(),
            17usize.pow(3) + 33usize.pow(3) + 65usize.pow(3) + 13 * (1 << 19)
        );
    }

    #[test]
    fn corner_weights_sum_to_one_and_rows_stay_in_their_level() {
        let g = HashGridConfig {
            log2_table_size: 12,
            ..Default::default()
        }
        .layout();
        for p in [
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 1.0],
            [0.31, 0.77, 0.5],
            [-3.0, 2.0, f32::NAN],
        ] {
            for l in &g.levels {
                let (rows, w) = l.corners(p);
                assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{p:?} {w:?}");
                assert!(w.iter().all(|&w| (0.0..=1.0).contains(&w)));
                for r in rows {
                    assert!(
                        (l.offset..l.offset + l.size).contains(&r),
                        "{p:?} level {l:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_vertex_is_read_with_weight_one() {
        let l = HashGridConfig::default().layout().levels[0];
        // x·15 + ½ = 3 ⇒ x = 2.5/15: exactly vertex 3 on that axis.
        let x = 2.5 / 15.0;
        let (rows, w) = l.corners([x, x, x]);
        let i = w.iter().position(|&w| w > 0.999).unwrap();
        assert_eq!(rows[i], l.index(3, 3, 3));
    }

    #[test]
    fn bad_fields_are_named() {
        let e = HashGridConfig {
            levels: 0,
            ..Default::default()
        }
        .validate("hash_grid")
        .unwrap_err();
        assert!(e.to_string().contains("hash_grid.levels"), "{e}");
        let e = HashGridConfig {
            growth: 0.5,
            ..Default::default()
        }
        .validate("g")
        .unwrap_err();
        assert!(e.to_string().contains("g.growth"), "{e}");
    }
}
