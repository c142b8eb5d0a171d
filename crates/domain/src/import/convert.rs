//! Measured values to line integrals: counts normalised by their flat and dark fields and
//! logged, and the optional clipping of negative line integrals.

use crate::{Error, Result};
use ndarray::{Array3, ArrayView2};

/// Set the negative line integrals of `p` to zero (`clip_negative`); returns how many there were.
/// Noise makes a ray through air measure slightly more than the open beam; clipping removes the
/// negative half of that noise, so the air's mean rises above zero.
pub fn clip_negative(p: &mut Array3<f32>) -> usize {
    let mut n = 0;
    for x in p.iter_mut().filter(|x| **x < 0.0) {
        *x = 0.0;
        n += 1;
    }
    n
}

/// `−ln((I − D) / (F − D))` per pixel of every image of `counts`, with `I − D` raised to
/// `min_counts` where smaller; returns the line integrals and how many pixels were raised.
/// `F − D ≤ 0` anywhere is an error naming the pixel.
pub fn line_integrals(
    counts: Array3<f32>,
    flat: ArrayView2<f32>,
    dark: ArrayView2<f32>,
    min_counts: f64,
) -> Result<(Array3<f32>, usize)> {
    normalise(counts, flat, dark, min_counts, None, |t| -t.ln() as f32)
}

/// The transmission `(I − D) / (F − D)` of every image of `counts`: [`line_integrals`] before
/// the log. Pixels marked in `skip` (bad pixels, to be repaired) are set to 1 and not checked.
pub fn transmission(
    counts: Array3<f32>,
    flat: ArrayView2<f32>,
    dark: ArrayView2<f32>,
    min_counts: f64,
    skip: Option<&ndarray::Array2<bool>>,
) -> Result<(Array3<f32>, usize)> {
    normalise(counts, flat, dark, min_counts, skip, |t| t as f32)
}

/// `out((I − D) / (F − D))` per pixel (in f64), `I − D` raised to `min_counts`; `out(1)` at the
/// pixels marked in `skip`.
fn normalise(
    mut counts: Array3<f32>,
    flat: ArrayView2<f32>,
    dark: ArrayView2<f32>,
    min_counts: f64,
    skip: Option<&ndarray::Array2<bool>>,
    out: impl Fn(f64) -> f32,
) -> Result<(Array3<f32>, usize)> {
    let beam = &flat - &dark;
    let skipped = |p: (usize, usize)| skip.is_some_and(|s| s[p]);
    if let Some(((r, c), v)) = beam
        .indexed_iter()
        .find(|(p, v)| !skipped(*p) && v.partial_cmp(&&0.0) != Some(std::cmp::Ordering::Greater))
    {
        return Err(Error::invalid(
            format!("flat[{r}][{c}]"),
            format!("the flat field does not exceed the dark field there (F − D = {v})"),
        ));
    }
    let mut raised = 0;
    for mut image in counts.outer_iter_mut() {
        ndarray::Zip::indexed(&mut image)
            .and(&dark)
            .and(&beam)
            .for_each(|p, v, &d, &b| {
                if skipped(p) {
                    *v = out(1.0);
                    return;
                }
                let net = *v as f64 - d as f64;
                let net = if net < min_counts {
                    raised += 1;
                    min_counts
                } else {
                    net
                };
                *v = out(net / b as f64);
            });
    }
    Ok((counts, raised))
}
