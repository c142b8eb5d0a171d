//! The discrete gradient of a stack of channel volumes and its exact adjoint, for total-variation
//! regularisers.
//!
//! Forward differences with a zero difference at the grid's last plane (Neumann boundary):
//! `(∇x)_d[i] = x[i + e_d] − x[i]` where `i + e_d` lies in the grid, else 0, for the three axes
//! `d = x, y, z`. Differences are per voxel step (not divided by the voxel size), so a gradient
//! has μ's unit, mm⁻¹.
//!
//! Layout: volumes `[z][y][x]` (row-major slices). A field of gradients over `C` channels is one
//! flat slice `[voxel][channel][axis]` (`3·C` values per voxel, axes in the order x, y, z), so a
//! regulariser that couples channels at a voxel ([`super::tv`]) reads one contiguous group.

use rayon::prelude::*;

/// Grid sizes `[nz, ny, nx]` of the volumes a [`Gradient`] acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Gradient {
    pub nz: usize,
    pub ny: usize,
    pub nx: usize,
}

impl Gradient {
    pub fn new(shape_zyx: [usize; 3]) -> Self {
        let [nz, ny, nx] = shape_zyx;
        Gradient { nz, ny, nx }
    }

    /// Voxels per volume.
    pub fn voxels(&self) -> usize {
        self.nz * self.ny * self.nx
    }

    /// Index strides of the axes x, y, z in a `[z][y][x]` slice.
    fn strides(&self) -> [usize; 3] {
        [1, self.nx, self.nx * self.ny]
    }

    /// Whether voxel `i` has a neighbour one step up each axis (x, y, z).
    fn inner(&self, i: usize) -> [bool; 3] {
        let x = i % self.nx;
        let y = (i / self.nx) % self.ny;
        let z = i / (self.nx * self.ny);
        [x + 1 < self.nx, y + 1 < self.ny, z + 1 < self.nz]
    }

    /// Whether voxel `i` has a neighbour one step down each axis (x, y, z).
    fn has_lower(&self, i: usize) -> [bool; 3] {
        let x = i % self.nx;
        let y = (i / self.nx) % self.ny;
        let z = i / (self.nx * self.ny);
        [x > 0, y > 0, z > 0]
    }

    /// The three forward differences of `x` at voxel `i` (x, y, z order).
    #[inline]
    pub fn at(&self, x: &[f32], i: usize) -> [f32; 3] {
        let s = self.strides();
        let inner = self.inner(i);
        std::array::from_fn(|d| if inner[d] { x[i + s[d]] - x[i] } else { 0.0 })
    }

    /// `∇x` of each channel volume into `out` (`[voxel][channel][axis]`, length `3·C·N`).
    pub fn apply(&self, volumes: &[&[f32]], out: &mut [f32]) {
        let c = volumes.len();
        assert_eq!(out.len(), 3 * c * self.voxels(), "gradient field length");
        out.par_chunks_mut(3 * c)
            .enumerate()
            .for_each(|(i, group)| {
                for (k, x) in volumes.iter().enumerate() {
                    group[3 * k..3 * k + 3].copy_from_slice(&self.at(x, i));
                }
            });
    }

    /// `(∇ᵀ q)[i]` of channel `k` of the field `q` (`[voxel][channel][axis]`, `channels` wide):
    /// the adjoint of [`Gradient::apply`], i.e. minus the discrete divergence.
    #[inline]
    pub fn adjoint_at(&self, q: &[f32], channels: usize, k: usize, i: usize) -> f32 {
        let s = self.strides();
        let inner = self.inner(i);
        let lower = self.has_lower(i);
        let g = 3 * channels;
        let mut v = 0.0;
        for d in 0..3 {
            if inner[d] {
                v -= q[i * g + 3 * k + d];
            }
            if lower[d] {
                v += q[(i - s[d]) * g + 3 * k + d];
            }
        }
        v
    }

    /// `∇ᵀ q` of channel `k` as a volume.
    pub fn adjoint(&self, q: &[f32], channels: usize, k: usize) -> Vec<f32> {
        (0..self.voxels())
            .into_par_iter()
            .map(|i| self.adjoint_at(q, channels, k, i))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` uniform values in [−1, 1), seeded.
    fn random(n: usize, seed: u64) -> Vec<f32> {
        prism_domain::testing::random([1, 1, n], seed)
            .into_iter()
            .collect()
    }

    #[test]
    fn the_adjoint_identity_holds_for_every_channel() {
        // ⟨∇x, q⟩ = ⟨x, ∇ᵀq⟩ exactly up to float rounding; an odd-sized grid catches swapped
        // axes and boundary planes.
        let g = Gradient::new([4, 5, 6]);
        let n = g.voxels();
        let xs: Vec<Vec<f32>> = (0..2).map(|k| random(n, k)).collect();
        let q = random(3 * 2 * n, 7);
        let mut grad = vec![0.0; 3 * 2 * n];
        g.apply(&[&xs[0], &xs[1]], &mut grad);
        let lhs: f64 = grad.iter().zip(&q).map(|(a, b)| (a * b) as f64).sum();
        let rhs: f64 = (0..2)
            .map(|k| {
                let a = g.adjoint(&q, 2, k);
                a.iter()
                    .zip(&xs[k])
                    .map(|(a, b)| (a * b) as f64)
                    .sum::<f64>()
            })
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-5 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
    }

    #[test]
    fn a_ramp_has_a_constant_gradient_inside_and_zero_at_the_last_plane() {
        // x[z][y][x] = 1·x + 10·y + 100·z.
        let g = Gradient::new([3, 3, 3]);
        let vol: Vec<f32> = (0..27)
            .map(|i| (i % 3) as f32 + 10.0 * ((i / 3) % 3) as f32 + 100.0 * (i / 9) as f32)
            .collect();
        assert_eq!(g.at(&vol, 0), [1.0, 10.0, 100.0]);
        // The voxel at x = 2, y = 1, z = 0: no x neighbour above it.
        assert_eq!(g.at(&vol, 2 + 3), [0.0, 10.0, 100.0]);
        assert_eq!(g.at(&vol, 26), [0.0, 0.0, 0.0]);
    }
}
