//! Directional TV's guide (Ehrhardt & Betcke 2016; Cueva et al.'s synergistic multi-spectral CT):
//! at every voxel the projection `P = I − ξξᵀ` that removes from a gradient its part along the
//! guide image's edges, with
//!
//! ```text
//! ξ = ∇g / √(|∇g|² + η²),   η = eta · max |∇g|
//! ```
//!
//! `∇` is [`Gradient`]'s forward difference (per voxel step), so `η` relative to the guide's
//! largest gradient makes `eta` free of units (Cueva et al.'s code scales it the same way). Where
//! the guide is flat (`|∇g| ≪ η`) `P ≈ I` and directional TV is TV; across a strong edge `|ξ| → 1`
//! and a gradient along `∇g` costs almost nothing. `P` is symmetric, so `(P∇)ᵀ = ∇ᵀP`.

use super::gradient::Gradient;
use ndarray::ArrayView3;
use rayon::prelude::*;

/// The guide's `ξ` at every voxel of a `[z][y][x]` grid.
#[derive(Clone, Debug)]
pub struct Directions {
    xi: Vec<[f32; 3]>,
    /// The largest row sum of `|P|` over the voxels, at least 1: `P∇`'s row and column sums
    /// are at most this times `∇`'s (the steps of a preconditioned primal–dual solver).
    bound: f32,
}

impl Directions {
    /// The directions of `guide` with edge parameter `eta` (> 0) relative to its largest
    /// gradient. A flat guide gives `ξ = 0` everywhere (`P = I`).
    pub fn of(guide: ArrayView3<f32>, eta: f64) -> Self {
        let shape = guide.shape();
        let grad = Gradient::new([shape[0], shape[1], shape[2]]);
        let g = guide.as_standard_layout();
        let g = g.as_slice().expect("standard layout");
        let grads: Vec<[f32; 3]> = (0..grad.voxels())
            .into_par_iter()
            .map(|i| grad.at(g, i))
            .collect();
        let max2 = grads
            .iter()
            .map(|d| d.iter().map(|&a| (a as f64).powi(2)).sum::<f64>())
            .fold(0.0f64, f64::max);
        let eta2 = eta * eta * max2;
        let xi: Vec<[f32; 3]> = grads
            .par_iter()
            .map(|d| {
                let n2 = d.iter().map(|&a| (a as f64).powi(2)).sum::<f64>();
                let den = (n2 + eta2).sqrt();
                if den > 0.0 {
                    d.map(|a| (a as f64 / den) as f32)
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        let bound = xi
            .par_iter()
            .map(|x| {
                (0..3)
                    .map(|r| (0..3).map(|c| p(x, r, c).abs()).sum::<f32>())
                    .fold(0.0f32, f32::max)
            })
            .reduce(|| 1.0, f32::max)
            .max(1.0);
        Directions { xi, bound }
    }

    /// The factor by which `P∇`'s row and column sums may exceed `∇`'s (≥ 1; 1 for a flat guide).
    pub fn bound(&self) -> f32 {
        self.bound
    }

    /// Voxels of the grid.
    pub fn voxels(&self) -> usize {
        self.xi.len()
    }

    /// `P v` at voxel `i`.
    #[inline]
    pub fn project(&self, i: usize, v: [f32; 3]) -> [f32; 3] {
        let x = &self.xi[i];
        let along = x[0] * v[0] + x[1] * v[1] + x[2] * v[2];
        std::array::from_fn(|d| v[d] - x[d] * along)
    }
}

/// Entry `(r, c)` of `I − ξξᵀ`.
fn p(x: &[f32; 3], r: usize, c: usize) -> f32 {
    (r == c) as u8 as f32 - x[r] * x[c]
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

    #[test]
    fn a_flat_guide_projects_nothing_and_an_edge_removes_the_gradient_along_it() {
        let flat = Directions::of(Array3::<f32>::from_elem((1, 4, 5), 2.0).view(), 0.01);
        assert_eq!(flat.bound(), 1.0);
        assert_eq!(flat.project(3, [1.0, -2.0, 0.5]), [1.0, -2.0, 0.5]);
        // A step along x at x = 2: at the edge ξ = (1/√(1 + η²), 0, 0), so P keeps the share
        // η²/(1 + η²) of a gradient along x and all of one along y.
        let step = Array3::from_shape_fn((1, 4, 5), |(_, _, x)| if x >= 2 { 1.0f32 } else { 0.0 });
        let d = Directions::of(step.view(), 0.1);
        let edge = 1; // voxel (y 0, x 1): its forward x-difference crosses the step
        let [px, py, pz] = d.project(edge, [1.0, 1.0, 0.0]);
        assert!((px - 0.01 / 1.01).abs() < 1e-6, "{px}");
        assert!((py - 1.0).abs() < 1e-6 && pz == 0.0, "{py} {pz}");
        // Off the edge the guide is flat: P = I there.
        assert_eq!(d.project(3, [1.0, 1.0, 0.0]), [1.0, 1.0, 0.0]);
        assert!(d.bound() >= 1.0 && d.bound() <= 2.0, "{}", d.bound());
    }

    #[test]
    fn the_bound_is_the_largest_row_sum_of_p() {
        // A diagonal ramp: ∇g = (1, 1, 0) in the interior, |ξ|² = 2/(2 + η²·2) with η relative
        // to max|∇g| = √2, so ξ = (a, a, 0), a = 1/√(2 + 2·eta²); the row sums of |P| are
        // 1 − a² + a² = 1 for the x and y rows and 1 for z: bound 1. With eta → 0 the same.
        let ramp = Array3::from_shape_fn((1, 6, 6), |(_, y, x)| (x + y) as f32);
        let d = Directions::of(ramp.view(), 0.1);
        assert!((d.bound() - 1.0).abs() < 1e-6, "{}", d.bound());
        // A 3-D diagonal ramp: ξ = (a, a, a), rows 1 − a² + 2a², a² = 1/(3 + 3·eta²).
        let ramp3 = Array3::from_shape_fn((5, 5, 5), |(z, y, x)| (x + y + z) as f32);
        let eta = 0.1f64;
        let d = Directions::of(ramp3.view(), eta);
        let a2 = 1.0 / (3.0 + 3.0 * eta * eta);
        assert!(
            (d.bound() as f64 - (1.0 + a2)).abs() < 1e-5,
            "{}",
            d.bound()
        );
    }
}
