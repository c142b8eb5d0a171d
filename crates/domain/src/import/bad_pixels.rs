//! Bad detector pixels: found in the open beam `F − D` (flat less dark) and repaired in every
//! image before the log. A pixel is bad when its open beam is not positive (dead, or a dark
//! field above the flat), or differs from the median of its neighbours (the `(2·radius + 1)²`
//! window, itself left out) by more than `max_deviation` of that median (hot, weak or unstable
//! pixels, which flat-field correction does not fix). Each image's bad pixels take the median
//! of the good pixels in the same window; a window without one widens until it has one.

use crate::{Error, Result};
use ndarray::{Array2, Array3, ArrayView2};
use rayon::prelude::*;
use serde::Deserialize;

/// `bad_pixels:` of an import config.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BadPixelConfig {
    /// Largest relative deviation of a pixel's open beam from its neighbours' median (0.5: a
    /// pixel at less than half or more than 1.5 times its neighbours is bad).
    #[serde(default = "default_deviation")]
    pub max_deviation: f64,
    /// Half-width of the neighbourhood, pixels (a 5 × 5 window at 2).
    #[serde(default = "default_radius")]
    pub radius: usize,
}

fn default_deviation() -> f64 {
    0.5
}

fn default_radius() -> usize {
    2
}

impl BadPixelConfig {
    /// `max_deviation` finite and > 0, `radius` ≥ 1.
    pub fn validate(&self) -> Result<()> {
        if !(self.max_deviation.is_finite() && self.max_deviation > 0.0) {
            return Err(Error::invalid(
                "bad_pixels.max_deviation",
                format!("must be finite and > 0, got {}", self.max_deviation),
            ));
        }
        if self.radius == 0 {
            return Err(Error::invalid("bad_pixels.radius", "must be at least 1"));
        }
        Ok(())
    }

    /// The bad pixels of a detector whose open beam is `beam` (`F − D`, `[rows][cols]`); an
    /// error when every pixel is bad.
    pub fn find(&self, beam: ArrayView2<f32>) -> Result<Array2<bool>> {
        self.validate()?;
        let (rows, cols) = beam.dim();
        let r = self.radius as isize;
        let mut window = Vec::new();
        let bad = Array2::from_shape_fn((rows, cols), |(i, j)| {
            let b = beam[[i, j]];
            if b.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return true;
            }
            window.clear();
            for di in -r..=r {
                for dj in -r..=r {
                    let (y, x) = (i as isize + di, j as isize + dj);
                    if (di, dj) != (0, 0) && inside(y, x, rows, cols) {
                        let v = beam[[y as usize, x as usize]];
                        if v > 0.0 {
                            window.push(v);
                        }
                    }
                }
            }
            match median(&mut window) {
                Some(m) => ((b / m) as f64 - 1.0).abs() > self.max_deviation,
                None => false,
            }
        });
        if bad.iter().all(|&b| b) {
            return Err(Error::invalid(
                "bad_pixels",
                "every detector pixel is bad: check the flat and dark fields",
            ));
        }
        Ok(bad)
    }

    /// Give every bad pixel of every image of `stack` (`[views][rows][cols]`) the median of the
    /// good pixels around it.
    pub fn repair(&self, stack: &mut Array3<f32>, bad: &Array2<bool>) {
        let (rows, cols) = bad.dim();
        let spots: Vec<(usize, usize)> = bad
            .indexed_iter()
            .filter(|(_, b)| **b)
            .map(|(p, _)| p)
            .collect();
        if spots.is_empty() {
            return;
        }
        if !stack.is_standard_layout() {
            *stack = stack.as_standard_layout().to_owned();
        }
        let data = stack.as_slice_mut().expect("a standard-layout stack");
        data.par_chunks_mut(rows * cols)
            .for_each_init(Vec::new, |window, image| {
                for &(i, j) in &spots {
                    let mut r = self.radius as isize;
                    let value = loop {
                        window.clear();
                        for y in i as isize - r..=i as isize + r {
                            for x in j as isize - r..=j as isize + r {
                                if inside(y, x, rows, cols) && !bad[[y as usize, x as usize]] {
                                    window.push(image[y as usize * cols + x as usize]);
                                }
                            }
                        }
                        if let Some(m) = median(window) {
                            break m;
                        }
                        if r as usize > rows.max(cols) {
                            // No good pixel anywhere (`find` refuses such a detector).
                            break image[i * cols + j];
                        }
                        r *= 2;
                    };
                    image[i * cols + j] = value;
                }
            });
    }
}

fn inside(y: isize, x: isize, rows: usize, cols: usize) -> bool {
    y >= 0 && x >= 0 && (y as usize) < rows && (x as usize) < cols
}

/// The median of `v` (the upper one of an even count), `None` when empty.
fn median(v: &mut [f32]) -> Option<f32> {
    if v.is_empty() {
        return None;
    }
    let k = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    Some(*m)
}
