//! Ramp filtering of detector rows for FDK/FBP.
//!
//! The filter is the band-limited Ram-Lak kernel sampled at the detector pitch (pixel units):
//! `h(0) = 1/4`, `h(n) = −1/(πn)²` for odd `n`, `0` for even `n ≠ 0` (Kak & Slaney, eq. 3.61 with
//! τ = 1). Its DFT over the padded length gives a real, even frequency response ≈ `|ω|/(2π)` for
//! ω ∈ [−π, π] (rad/pixel), which a [`Window`] then apodises. Rows are zero-padded to the next power
//! of two ≥ 2·cols (at least 64) so the circular convolution equals the linear one. Filtering in
//! pixel units means the caller divides by the pitch (see `fdk`).
//!
//! FFTs use `rustfft` (maintained, pure Rust, SIMD); two real rows are filtered per complex FFT
//! (one in the real part, one in the imaginary part), which is exact because the response is real
//! and even.

use crate::{Error, Result};
use ndarray::Array3;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::str::FromStr;
use std::sync::Arc;

/// Apodisation window of the ramp filter, as a function of ω ∈ [0, π] (cut-off at Nyquist).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Window {
    /// 1 (the plain ramp).
    #[default]
    #[serde(alias = "ram_lak", alias = "ramlak", alias = "ramp")]
    RamLak,
    /// `sin(ω/2)/(ω/2)`.
    #[serde(alias = "shepp_logan")]
    SheppLogan,
    /// `cos(ω/2)`.
    Cosine,
    /// `0.54 + 0.46·cos ω`.
    Hamming,
    /// `(1 + cos ω)/2`.
    Hann,
}

impl Window {
    /// All windows, in documentation order.
    pub const ALL: [Window; 5] = [
        Window::RamLak,
        Window::SheppLogan,
        Window::Cosine,
        Window::Hamming,
        Window::Hann,
    ];

    /// Canonical name (`ram-lak`, `shepp-logan`, `cosine`, `hamming`, `hann`).
    pub fn name(self) -> &'static str {
        match self {
            Window::RamLak => "ram-lak",
            Window::SheppLogan => "shepp-logan",
            Window::Cosine => "cosine",
            Window::Hamming => "hamming",
            Window::Hann => "hann",
        }
    }

    /// Window value at ω ∈ [0, π] rad/pixel.
    pub fn at(self, w: f64) -> f64 {
        match self {
            Window::RamLak => 1.0,
            Window::SheppLogan => {
                if w == 0.0 {
                    1.0
                } else {
                    (w / 2.0).sin() / (w / 2.0)
                }
            }
            Window::Cosine => (w / 2.0).cos(),
            Window::Hamming => 0.54 + 0.46 * w.cos(),
            Window::Hann => 0.5 * (1.0 + w.cos()),
        }
    }
}

impl FromStr for Window {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        let key = s.trim().to_ascii_lowercase().replace('_', "-");
        Window::ALL
            .into_iter()
            .find(|w| w.name() == key || (key == "ramp" && *w == Window::RamLak))
            .ok_or_else(|| {
                Error::invalid(
                    "filter",
                    format!(
                        "unknown filter `{s}`; expected one of ram-lak, shepp-logan, cosine, hamming, hann"
                    ),
                )
            })
    }
}

/// A ramp filter planned for one detector width.
pub struct RampFilter {
    cols: usize,
    /// Real frequency response over the padded length.
    response: Vec<f32>,
    fwd: Arc<dyn Fft<f32>>,
    inv: Arc<dyn Fft<f32>>,
}

impl RampFilter {
    /// Plan the filter for rows of `cols` pixels with `window`.
    pub fn new(cols: usize, window: Window) -> Result<Self> {
        if cols == 0 {
            return Err(Error::invalid("detector.cols", "must be at least 1"));
        }
        let len = padded_len(cols);
        let mut planner = FftPlanner::<f32>::new();
        let fwd = planner.plan_fft_forward(len);
        let inv = planner.plan_fft_inverse(len);
        // Spatial kernel, wrapped (negative lags at the end), in f64 then transformed.
        let mut kernel = vec![Complex32::new(0.0, 0.0); len];
        kernel[0].re = 0.25;
        for n in (1..len / 2).step_by(2) {
            let h = (-1.0 / (PI * n as f64).powi(2)) as f32;
            kernel[n].re = h;
            kernel[len - n].re = h;
        }
        fwd.process(&mut kernel);
        let response = (0..len)
            .map(|k| {
                let kk = k.min(len - k);
                let w = 2.0 * PI * kk as f64 / len as f64;
                // Imaginary parts vanish up to rounding (even kernel); scale 1/len for the
                // unnormalised inverse FFT.
                (kernel[k].re as f64 * window.at(w) / len as f64) as f32
            })
            .collect();
        Ok(RampFilter {
            cols,
            response,
            fwd,
            inv,
        })
    }

    /// Padded FFT length.
    pub fn len(&self) -> usize {
        self.response.len()
    }

    /// Never true (the padded length is at least 64).
    pub fn is_empty(&self) -> bool {
        self.response.is_empty()
    }

    /// Frequency response (including the 1/len of the inverse transform) at bin `k`.
    pub fn response(&self) -> &[f32] {
        &self.response
    }

    /// Filter every row of `projections` (`[view][row][col]`) in place.
    pub fn apply(&self, projections: &mut Array3<f32>) -> Result<()> {
        if projections.shape()[2] != self.cols {
            return Err(Error::invalid(
                "projections",
                format!(
                    "rows have {} pixels, the filter was planned for {}",
                    projections.shape()[2],
                    self.cols
                ),
            ));
        }
        let (rows, cols) = (projections.shape()[1], self.cols);
        projections
            .as_slice_mut()
            .ok_or_else(|| Error::invalid("projections", "must be in standard (C) layout"))?
            .par_chunks_mut(rows * cols)
            .for_each(|view| {
                let len = self.len();
                let mut buf = vec![Complex32::new(0.0, 0.0); len];
                let mut scratch = vec![
                    Complex32::new(0.0, 0.0);
                    self.fwd
                        .get_inplace_scratch_len()
                        .max(self.inv.get_inplace_scratch_len())
                ];
                let mut r = 0;
                while r < rows {
                    let pair = r + 1 < rows;
                    buf.iter_mut().for_each(|z| *z = Complex32::new(0.0, 0.0));
                    for (c, z) in buf.iter_mut().take(self.cols).enumerate() {
                        z.re = view[r * cols + c];
                        if pair {
                            z.im = view[(r + 1) * cols + c];
                        }
                    }
                    self.fwd.process_with_scratch(&mut buf, &mut scratch);
                    for (z, h) in buf.iter_mut().zip(&self.response) {
                        *z *= *h;
                    }
                    self.inv.process_with_scratch(&mut buf, &mut scratch);
                    for (c, z) in buf.iter().take(self.cols).enumerate() {
                        view[r * cols + c] = z.re;
                        if pair {
                            view[(r + 1) * cols + c] = z.im;
                        }
                    }
                    r += 2;
                }
            });
        Ok(())
    }
}

/// Next power of two ≥ 2·cols, at least 64.
pub fn padded_len(cols: usize) -> usize {
    (2 * cols).next_power_of_two().max(64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn padding_is_next_power_of_two_of_twice_the_width() {
        assert_eq!(padded_len(1), 64);
        assert_eq!(padded_len(100), 256);
        assert_eq!(padded_len(128), 256);
        assert_eq!(padded_len(129), 512);
    }

    #[test]
    fn ram_lak_response_approximates_the_ramp() {
        // The DFT of the sampled band-limited kernel is |ω|/(2π) up to the truncation of the
        // 1/n² tail; it is exactly 0 at DC only in the limit, bounded by Σ_{|n|≥len/2} |h(n)|.
        let f = RampFilter::new(128, Window::RamLak).unwrap();
        let len = f.len() as f64;
        // Σ over odd |n| ≥ len/2 of 1/(πn)² ≤ 2/π² · 1/(len − 2) (integral bound).
        let tail = 2.0 / (PI * PI) / (len - 2.0);
        for k in 0..=f.len() / 2 {
            let w = 2.0 * PI * k as f64 / len;
            let h = f.response()[k] as f64 * len;
            assert!(
                (h - w / (2.0 * PI)).abs() < tail + 1e-6,
                "bin {k}: {h} vs {}",
                w / (2.0 * PI)
            );
        }
    }

    #[test]
    fn filtering_matches_direct_convolution() {
        // Circular FFT filtering with ≥ 2n padding equals the linear convolution with the
        // truncated kernel, checked against a direct O(n²) sum (Ram-Lak, where the kernel is known
        // in closed form).
        let cols = 37;
        let mut p = Array3::from_shape_fn((2, 3, cols), |(v, r, c)| {
            ((v * 7 + r * 3 + c) as f32 * 0.37).sin() + 0.5
        });
        let orig = p.clone();
        RampFilter::new(cols, Window::RamLak)
            .unwrap()
            .apply(&mut p)
            .unwrap();
        let h = |n: i64| -> f64 {
            if n == 0 {
                0.25
            } else if n % 2 == 0 {
                0.0
            } else {
                -1.0 / (PI * n as f64).powi(2)
            }
        };
        for v in 0..2 {
            for r in 0..3 {
                for c in 0..cols {
                    let want: f64 = (0..cols)
                        .map(|m| h(c as i64 - m as i64) * orig[[v, r, m]] as f64)
                        .sum();
                    assert!((p[[v, r, c]] as f64 - want).abs() < 1e-5, "{v} {r} {c}");
                }
            }
        }
    }

    #[test]
    fn windows_attenuate_high_frequencies_only() {
        for w in Window::ALL {
            assert!((w.at(0.0) - 1.0).abs() < 1e-12, "{w:?}");
            assert!(w.at(PI) <= 1.0 + 1e-12);
        }
        assert!((Window::Hann.at(PI)).abs() < 1e-12);
        assert!((Window::Hamming.at(PI) - 0.08).abs() < 1e-12);
        assert!((Window::SheppLogan.at(PI) - 2.0 / PI).abs() < 1e-12);
        assert!((Window::Cosine.at(PI)).abs() < 1e-12);
    }

    #[test]
    fn names_parse_and_unknown_names_are_rejected() {
        for w in Window::ALL {
            assert_eq!(w.name().parse::<Window>().unwrap(), w);
        }
        assert_eq!("shepp_logan".parse::<Window>().unwrap(), Window::SheppLogan);
        assert_eq!("Ram-Lak".parse::<Window>().unwrap(), Window::RamLak);
        let e = "butterworth".parse::<Window>().unwrap_err().to_string();
        assert!(e.contains("filter") && e.contains("butterworth"), "{e}");
        let y: Window = serde_yaml_ng::from_str("hann").unwrap();
        assert_eq!(y, Window::Hann);
        assert!(serde_yaml_ng::from_str::<Window>("gauss").is_err());
    }
}
