//! The total variation of `[M, Z, Y, X]` volumes and its gradient, on `&[f32]` buffers (rayon
//! over the `M·Z` slices).
//!
//! `TV = (Σ|Δx| + Σ|Δy| + Σ|Δz|) / n` with forward differences `Δ_a v(p) = v(p + e_a) − v(p)`
//! inside each volume and `n` their number. Its gradient at voxel `p` is `(g / n) · k(p)`, with
//! `k(p) = Σ_a sign(Δ_a v(p − e_a)) − sign(Δ_a v(p))` over the differences that exist (sign 0 at
//! 0, as Burn's `abs` backward): an integer in [−6, 6], so the gradient is one rounding of an
//! exact value. The same formula, composed of Burn ops, is
//! [`crate::gaussians::train::loss::composed_total_variation`].

use rayon::prelude::*;

/// Volumes `[m, z, y, x]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dims {
    pub m: usize,
    pub z: usize,
    pub y: usize,
    pub x: usize,
}

impl Dims {
    /// From a `[M, Z, Y, X]` shape.
    pub fn of(shape: &[usize]) -> Self {
        let [m, z, y, x] = shape
            .try_into()
            .expect("total variation takes [M, Z, Y, X] volumes");
        Self { m, z, y, x }
    }

    fn slice(self) -> usize {
        self.y * self.x
    }

    fn len(self) -> usize {
        self.m * self.z * self.slice()
    }

    /// The number of forward differences `n` (0 when every axis has one voxel).
    pub fn differences(self) -> usize {
        let vol = self.len();
        [self.z, self.y, self.x]
            .iter()
            .filter(|&&n| n > 1)
            .map(|&n| vol / n * (n - 1))
            .sum()
    }
}

fn sign(d: f32) -> i32 {
    (d > 0.0) as i32 - (d < 0.0) as i32
}

/// `TV` of `v` (0 when there is no difference). Slice sums in f64, added in slice order: the
/// same value whatever the thread count.
pub fn total_variation(d: Dims, v: &[f32]) -> f32 {
    assert_eq!(
        v.len(),
        d.len(),
        "total variation: the values are not [M, Z, Y, X]"
    );
    let n = d.differences();
    if n == 0 {
        return 0.0;
    }
    let (s, w) = (d.slice(), d.x);
    let sums: Vec<f64> = (0..d.m * d.z)
        .into_par_iter()
        .map(|q| {
            let here = &v[q * s..(q + 1) * s];
            let mut sum = 0.0f64;
            for r in 0..d.y {
                let row = &here[r * w..(r + 1) * w];
                for pair in row.windows(2) {
                    sum += (pair[1] - pair[0]).abs() as f64;
                }
                if r + 1 < d.y {
                    let next = &here[(r + 1) * w..(r + 2) * w];
                    for (a, b) in row.iter().zip(next) {
                        sum += (b - a).abs() as f64;
                    }
                }
            }
            if q % d.z + 1 < d.z {
                let next = &v[(q + 1) * s..(q + 2) * s];
                for (a, b) in here.iter().zip(next) {
                    sum += (b - a).abs() as f64;
                }
            }
            sum
        })
        .collect();
    (sums.iter().sum::<f64>() / n as f64) as f32
}

/// The gradient of `g · TV(v)` with respect to `v`.
pub fn total_variation_backward(d: Dims, v: &[f32], g: f32) -> Vec<f32> {
    assert_eq!(
        v.len(),
        d.len(),
        "total variation: the values are not [M, Z, Y, X]"
    );
    let mut out = vec![0.0f32; v.len()];
    let n = d.differences();
    if n == 0 {
        return out;
    }
    let scale = g / n as f32;
    let (s, w) = (d.slice(), d.x);
    out.par_chunks_mut(s).enumerate().for_each(|(q, o)| {
        let zi = q % d.z;
        let base = q * s;
        for (i, o) in o.iter_mut().enumerate() {
            let (r, c) = (i / w, i % w);
            let p = v[base + i];
            let mut k = 0;
            if c + 1 < w {
                k -= sign(v[base + i + 1] - p);
            }
            if c > 0 {
                k += sign(p - v[base + i - 1]);
            }
            if r + 1 < d.y {
                k -= sign(v[base + i + w] - p);
            }
            if r > 0 {
                k += sign(p - v[base + i - w]);
            }
            if zi + 1 < d.z {
                k -= sign(v[base + s + i] - p);
            }
            if zi > 0 {
                k += sign(p - v[base - s + i]);
            }
            *o = k as f32 * scale;
        }
    });
    out
}
