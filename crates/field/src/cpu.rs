//! CPU kernels of the hash-grid encoder (plain slices in, `Vec<f32>` out), registered for every
//! CPU backend in [`crate::backend`].
//!
//! The forward splits the points over threads. The backward is a scatter-add into the table;
//! levels own disjoint rows, so it splits the levels over threads and needs no atomics (each
//! level's sum runs in point order: results are identical run to run).

use crate::grid::HashGrid;
use rayon::prelude::*;

/// Points per parallel task of the forward: level by level over a task's points, one level's
/// rows (512 KiB at 2^16 rows of 2 features) stay in the core's cache while the task's points,
/// neighbours along their rays, read them.
const CHUNK: usize = 8192;

/// Runs `$kernel::<F>` with the grid's feature count as a constant (1..=8, what
/// [`crate::grid::HashGridConfig::validate`] admits), so a point's F sums stay in registers.
macro_rules! by_features {
    ($f:expr, $kernel:ident($($arg:expr),*)) => {
        match $f {
            1 => $kernel::<1>($($arg),*),
            2 => $kernel::<2>($($arg),*),
            3 => $kernel::<3>($($arg),*),
            4 => $kernel::<4>($($arg),*),
            5 => $kernel::<5>($($arg),*),
            6 => $kernel::<6>($($arg),*),
            7 => $kernel::<7>($($arg),*),
            8 => $kernel::<8>($($arg),*),
            f => panic!("hash grid with {f} features per level (1..=8 are valid)"),
        }
    };
}

/// The encodings `[N, L·F]` of `points` `[N, 3]` with `table` `[rows, F]`.
pub fn encode(grid: &HashGrid, points: &[f32], table: &[f32]) -> Vec<f32> {
    by_features!(grid.features, encode_with(grid, points, table))
}

fn encode_with<const F: usize>(grid: &HashGrid, points: &[f32], table: &[f32]) -> Vec<f32> {
    let width = grid.width();
    let n = points.len() / 3;
    let mut out = vec![0f32; n * width];
    out.par_chunks_mut(CHUNK * width)
        .enumerate()
        .for_each(|(chunk, out)| {
            for (l, level) in grid.levels.iter().enumerate() {
                for (i, enc) in out.chunks_exact_mut(width).enumerate() {
                    let (rows, w) = level.corners(point(points, chunk * CHUNK + i));
                    // Summed from 0 in corner order, as into the zeroed output.
                    let mut acc = [0f32; F];
                    for (&r, &w) in rows.iter().zip(&w) {
                        let row: &[f32; F] = table[r as usize * F..(r as usize + 1) * F]
                            .try_into()
                            .expect("a row holds F features");
                        for (a, &t) in acc.iter_mut().zip(row) {
                            *a += w * t;
                        }
                    }
                    enc[l * F..(l + 1) * F].copy_from_slice(&acc);
                }
            }
        });
    out
}

/// The table's gradient `[rows, F]` of `⟨grad, encode(points, ·)⟩` (`grad` `[N, L·F]`); the
/// encoding is linear in the table, so this does not depend on the table's values.
pub fn encode_backward(grid: &HashGrid, points: &[f32], grad: &[f32]) -> Vec<f32> {
    by_features!(grid.features, encode_backward_with(grid, points, grad))
}

fn encode_backward_with<const F: usize>(grid: &HashGrid, points: &[f32], grad: &[f32]) -> Vec<f32> {
    let width = grid.width();
    let n = points.len() / 3;
    let mut out = vec![0f32; grid.rows() * F];
    // Split the table into the levels' disjoint row ranges.
    let mut parts = Vec::with_capacity(grid.levels.len());
    let mut rest = out.as_mut_slice();
    for level in &grid.levels {
        let (head, tail) = rest.split_at_mut(level.size as usize * F);
        parts.push((level, head));
        rest = tail;
    }
    parts
        .into_par_iter()
        .enumerate()
        .for_each(|(l, (level, rows_out))| {
            let base = level.offset as usize;
            for i in 0..n {
                let g: &[f32; F] = grad[i * width + l * F..i * width + (l + 1) * F]
                    .try_into()
                    .expect("a level's slice holds F features");
                if g.iter().all(|&g| g == 0.0) {
                    continue;
                }
                let (rows, w) = level.corners(point(points, i));
                for (&r, &w) in rows.iter().zip(&w) {
                    let r = r as usize - base;
                    for (o, &g) in rows_out[r * F..(r + 1) * F].iter_mut().zip(g) {
                        *o += w * g;
                    }
                }
            }
        });
    out
}

#[inline]
fn point(points: &[f32], i: usize) -> [f32; 3] {
    [points[3 * i], points[3 * i + 1], points[3 * i + 2]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::HashGridConfig;
    use crate::tests::random;

    fn small() -> HashGrid {
        HashGridConfig {
            levels: 4,
            features: 2,
            base_resolution: 4,
            growth: 1.7,
            log2_table_size: 6,
        }
        .layout()
    }

    #[test]
    fn a_linear_table_is_reproduced_exactly_on_dense_levels() {
        // Trilinear interpolation reproduces any function linear in the vertex coordinates: on a
        // dense level with table value a·i + b·j + c·k, the encoding is a·pos_x + b·pos_y + c·pos_z.
        let g = HashGridConfig {
            levels: 1,
            features: 1,
            base_resolution: 5,
            growth: 2.0,
            log2_table_size: 10,
        }
        .layout();
        let l = g.levels[0];
        assert!(l.dense);
        let mut table = vec![0f32; g.rows()];
        for k in 0..l.res {
            for j in 0..l.res {
                for i in 0..l.res {
                    table[l.index(i, j, k) as usize] =
                        1.0 * i as f32 - 2.0 * j as f32 + 0.5 * k as f32;
                }
            }
        }
        let pts = random(300, 0.0, 1.0, 1);
        let enc = encode(&g, &pts, &table);
        for (i, e) in enc.iter().enumerate() {
            let pos = |a: usize| pts[3 * i + a] * l.scale + 0.5;
            let want = pos(0) - 2.0 * pos(1) + 0.5 * pos(2);
            assert!((e - want).abs() < 2e-5, "point {i}: {e} vs {want}");
        }
    }

    #[test]
    fn the_backward_is_the_adjoint_of_the_forward() {
        // ⟨grad, E t⟩ = ⟨Eᵀ grad, t⟩ for the linear map E: table → encodings (hashed levels with
        // collisions included: 64-row tables).
        let g = small();
        assert!(g.levels.iter().any(|l| !l.dense));
        let n = 500;
        let pts = random(3 * n, -0.1, 1.1, 2);
        let table = random(g.rows() * g.features, -1.0, 1.0, 3);
        let grad = random(n * g.width(), -1.0, 1.0, 4);
        let enc = encode(&g, &pts, &table);
        let back = encode_backward(&g, &pts, &grad);
        let lhs: f64 = enc
            .iter()
            .zip(&grad)
            .map(|(a, b)| *a as f64 * *b as f64)
            .sum();
        let rhs: f64 = back
            .iter()
            .zip(&table)
            .map(|(a, b)| *a as f64 * *b as f64)
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-4 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
    }

    #[test]
    fn the_backward_matches_finite_differences_of_the_forward() {
        let g = small();
        let n = 40;
        let pts = random(3 * n, 0.0, 1.0, 5);
        let table = random(g.rows() * g.features, -1.0, 1.0, 6);
        let grad = random(n * g.width(), -1.0, 1.0, 7);
        let loss = |t: &[f32]| -> f64 {
            encode(&g, &pts, t)
                .iter()
                .zip(&grad)
                .map(|(a, b)| *a as f64 * *b as f64)
                .sum()
        };
        let back = encode_backward(&g, &pts, &grad);
        let h = 1e-2f32;
        for r in (0..table.len()).step_by(7) {
            let (mut up, mut down) = (table.clone(), table.clone());
            up[r] += h;
            down[r] -= h;
            let fd = (loss(&up) - loss(&down)) / (2.0 * h as f64);
            assert!(
                (fd - back[r] as f64).abs() < 2e-3,
                "row {r}: fd {fd} vs {}",
                back[r]
            );
        }
    }
}
