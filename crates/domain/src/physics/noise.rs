//! Detector noise on line-integral projections.
//!
//! For each pixel with line integral p the detector records `I = Poisson(I0·e^(−p)) + N(0, σ²)`
//! (quantum noise, then additive electronic noise in counts), and the noisy line integral is
//! `p̃ = −ln(max(I, COUNT_FLOOR) / I0)`. The floor keeps pixels with zero or negative counts
//! (photon starvation, electronic noise) finite: they read as `−ln(COUNT_FLOOR / I0)`.
//!
//! `I0` is the **physical** number of photons per detector pixel in an unattenuated ray. (TIGRE's
//! `addCTnoise` first rescales projections by their maximum; we do not, so the same I0 means the
//! same dose whatever the object.) For large counts `Var(p̃) ≈ (I0·e^(−p) + σ²) / (I0·e^(−p))²`.
//!
//! Reproducibility: each detector row of each view draws from its own ChaCha8 stream (key from
//! the seed, stream = `view·rows + row`), so the output depends on the seed only, not on the
//! number of threads.

use crate::{Error, Result};
use ndarray::Array3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Poisson, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Counts below this (zero or negative after electronic noise) are read as this many photons.
pub const COUNT_FLOOR: f64 = 0.5;

/// Photon and electronic noise of a detector pixel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseModel {
    /// Unattenuated photons per pixel (> 0).
    pub i0: f64,
    /// Standard deviation of the additive electronic noise, counts (≥ 0).
    #[serde(default)]
    pub electronic_sigma: f64,
}

impl NoiseModel {
    /// Errors name `i0` or `electronic_sigma`.
    pub fn validate(&self) -> Result<()> {
        if !(self.i0.is_finite() && self.i0 > 0.0) {
            return Err(Error::invalid(
                "i0",
                format!("{} photons per pixel must be finite and > 0", self.i0),
            ));
        }
        if !(self.electronic_sigma.is_finite() && self.electronic_sigma >= 0.0) {
            return Err(Error::invalid(
                "electronic_sigma",
                format!("{} counts must be finite and ≥ 0", self.electronic_sigma),
            ));
        }
        Ok(())
    }

    /// The noisy line integral of one pixel with line integral `p`.
    fn sample(&self, p: f64, rng: &mut ChaCha8Rng) -> f64 {
        let expected = self.i0 * (-p).exp();
        // `expected` is finite and ≤ Poisson::MAX_LAMBDA (checked by `add_noise`); it is 0 only
        // for an unreachable pixel (p = +∞ or underflow), which records no photons.
        let mut counts = match Poisson::new(expected) {
            Ok(d) => d.sample(rng),
            Err(_) => 0.0,
        };
        if self.electronic_sigma > 0.0 {
            let z: f64 = rng.sample(StandardNormal);
            counts += self.electronic_sigma * z;
        }
        -(counts.max(COUNT_FLOOR) / self.i0).ln()
    }
}

/// Replace line integrals `[view][row][col]` by noisy ones (see the module doc), deterministically
/// for `seed`. Errors name `i0`/`electronic_sigma`, or `proj` for a NaN or a line integral so
/// negative that the expected count exceeds what a Poisson sampler can represent; the array is
/// unchanged on error.
pub fn add_noise(proj: &mut Array3<f32>, model: &NoiseModel, seed: u64) -> Result<()> {
    model.validate()?;
    // Largest expected count the sampler accepts; p must keep I0·e^(−p) below it.
    let p_min = -(Poisson::<f64>::MAX_LAMBDA / model.i0).ln();
    if let Some((idx, v)) = proj
        .indexed_iter()
        .find(|(_, v)| v.is_nan() || (**v as f64) < p_min)
    {
        return Err(Error::invalid(
            "proj",
            format!("line integral {v} at [view, row, col] = {idx:?} is NaN or below {p_min:.1}"),
        ));
    }
    let cols = proj.dim().2;
    if proj.is_empty() {
        return Ok(());
    }
    let noisy_rows = |data: &mut [f32]| {
        data.par_chunks_mut(cols)
            .enumerate()
            .for_each(|(row, values)| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(row as u64);
                for v in values {
                    *v = model.sample(*v as f64, &mut rng) as f32;
                }
            });
    };
    match proj.as_slice_mut() {
        Some(data) => noisy_rows(data),
        None => {
            let mut standard = proj.as_standard_layout().into_owned();
            noisy_rows(standard.as_slice_mut().expect("standard layout"));
            proj.assign(&standard);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::ShapeBuilder;

    fn constant(p: f32, n: usize) -> Array3<f32> {
        Array3::from_elem((n, n, n), p)
    }

    fn mean_var(a: &Array3<f32>) -> (f64, f64) {
        let n = a.len() as f64;
        let mean = a.iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = a.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, var)
    }

    #[test]
    fn high_dose_is_unbiased_with_poisson_variance() {
        // p = 1, I0 = 1e5: expected count λ = 36788. Delta method: Var(p̃) = 1/λ = e/I0, bias
        // 1/(2λ) = 1.4e-5; higher-order terms are O(1/λ) relative (< 1e-4). With N = 32³
        // samples the standard error of the mean is sqrt(e/I0/N) = 2.9e-5 and the relative
        // standard error of the sample variance sqrt(2/N) = 0.8 %: we allow 6 standard errors.
        let n = 32;
        let samples = (n * n * n) as f64;
        let model = NoiseModel {
            i0: 1e5,
            electronic_sigma: 0.0,
        };
        let mut proj = constant(1.0, n);
        add_noise(&mut proj, &model, 7).unwrap();
        let (mean, var) = mean_var(&proj);
        let want_var = 1f64.exp() / model.i0;
        let se_mean = (want_var / samples).sqrt();
        assert!((mean - 1.0).abs() < 6.0 * se_mean + 1.4e-5, "mean {mean}");
        assert!(
            (var / want_var - 1.0).abs() < 6.0 * (2.0 / samples).sqrt(),
            "var {var} vs {want_var}"
        );

        // Electronic noise adds σ² counts of variance: Var = (λ + σ²)/λ².
        let model = NoiseModel {
            i0: 1e5,
            electronic_sigma: 200.0,
        };
        let mut proj = constant(1.0, n);
        add_noise(&mut proj, &model, 8).unwrap();
        let (_, var) = mean_var(&proj);
        let lambda = model.i0 * (-1f64).exp();
        let want_var = (lambda + 200.0 * 200.0) / (lambda * lambda);
        assert!(
            (var / want_var - 1.0).abs() < 6.0 * (2.0 / samples).sqrt(),
            "var {var} vs {want_var}"
        );
    }

    #[test]
    fn photon_starvation_stays_finite_at_the_floor() {
        let model = NoiseModel {
            i0: 1e4,
            electronic_sigma: 0.0,
        };
        let mut proj = Array3::from_elem((2, 3, 4), 1e4f32);
        proj[[0, 0, 0]] = f32::INFINITY;
        add_noise(&mut proj, &model, 1).unwrap();
        let floor = -(COUNT_FLOOR / model.i0).ln() as f32;
        assert!(proj.iter().all(|&v| v == floor), "{proj:?}");
        // With electronic noise, negative counts also read as the floor.
        let model = NoiseModel {
            i0: 1e4,
            electronic_sigma: 5.0,
        };
        let mut proj = Array3::from_elem((2, 3, 4), 100f32);
        add_noise(&mut proj, &model, 1).unwrap();
        assert!(proj.iter().all(|v| v.is_finite() && *v <= floor));
        assert!(proj.iter().any(|&v| v == floor));
    }

    #[test]
    fn deterministic_per_seed_and_independent_of_threads() {
        let model = NoiseModel {
            i0: 1e3,
            electronic_sigma: 2.0,
        };
        let base = Array3::from_shape_fn((4, 8, 8), |(v, r, c)| 0.1 * (v + r + c) as f32);
        let run = |seed, threads| {
            let mut p = base.clone();
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| add_noise(&mut p, &model, seed).unwrap());
            p
        };
        let a = run(42, 1);
        assert_eq!(a, run(42, 3));
        assert_ne!(a, run(43, 1));
        assert_ne!(a, base);
        // A non-standard (Fortran) layout gives the same values at the same [view][row][col].
        let mut f = Array3::zeros(base.raw_dim().f());
        f.assign(&base);
        add_noise(&mut f, &model, 42).unwrap();
        assert_eq!(f, a);
    }

    #[test]
    fn bad_inputs_name_their_fields() {
        let mut p = constant(1.0, 2);
        for (i0, sigma, field) in [
            (0.0, 0.0, "`i0`"),
            (-5.0, 0.0, "`i0`"),
            (f64::NAN, 0.0, "`i0`"),
            (1e3, -1.0, "`electronic_sigma`"),
        ] {
            let model = NoiseModel {
                i0,
                electronic_sigma: sigma,
            };
            let msg = add_noise(&mut p, &model, 0).unwrap_err().to_string();
            assert!(msg.contains(field), "{msg}");
        }
        let model = NoiseModel {
            i0: 1e3,
            electronic_sigma: 0.0,
        };
        p[[1, 1, 1]] = f32::NAN;
        let before = p.clone();
        let msg = add_noise(&mut p, &model, 0).unwrap_err().to_string();
        assert!(msg.contains("`proj`") && msg.contains("(1, 1, 1)"), "{msg}");
        assert!(
            p.iter()
                .zip(&before)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        p[[1, 1, 1]] = -100.0;
        assert!(add_noise(&mut p, &model, 0).is_err());
        let y: NoiseModel = serde_yaml_ng::from_str("i0: 2000").unwrap();
        assert_eq!(y.electronic_sigma, 0.0);
        assert!(serde_yaml_ng::from_str::<NoiseModel>("i0: 1\nsigma: 2").is_err());
    }
}
