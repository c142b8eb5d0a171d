//! The mean SSIM of a batch of images and its gradient with respect to the prediction, on
//! `&[f32]` buffers (rayon over images and windowed maps).
//!
//! Per image (H × W, zero padding), with `B` the separable Gaussian blur ([`window`]):
//!
//! ```text
//! μp = B p, μt = B t, Epp = B p², Ett = B t², Ept = B (p t)
//! A1 = 2 μp μt + C1,  A2 = 2 (Ept − μp μt) + C2
//! D1 = μp² + μt² + C1, D2 = (Epp − μp²) + (Ett − μt²) + C2
//! S  = A1 A2 / (D1 D2),  SSIM = mean of S over every pixel of every image
//! ```
//!
//! B is symmetric with zero padding, so it is its own adjoint, and the gradient of
//! `L = g · SSIM` is `∂p = B a + 2 p ⊙ B b + t ⊙ B c`, where per pixel (w = g / pixels,
//! Dn = D1 D2):
//!
//! ```text
//! a = w ∂S/∂μp  = w (2 μt (A2 − A1) − 2 μp S (D2 − D1)) / Dn
//! b = w ∂S/∂Epp = −w S / D2
//! c = w ∂S/∂Ept = 2 w A1 / Dn
//! ```
//!
//! Both divide by `Dn ≥ C1 C2 > 0` only where the variances are non-negative; f32 rounding can
//! make `Epp − μp²` slightly negative, which C2 absorbs. The same formula, composed of Burn
//! ops, is [`crate::gaussians::train::loss::SsimWindow::composed_ssim`].

use rayon::prelude::*;

use super::window::{C1, C2, SSIM_WINDOW, ssim_window};

/// Images `[images, h, w]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dims {
    pub images: usize,
    pub h: usize,
    pub w: usize,
}

impl Dims {
    fn plane(self) -> usize {
        self.h * self.w
    }
}

const R: usize = SSIM_WINDOW / 2;

/// Zero-padded separable blur of one `h × w` image: columns first, then rows (the order of the
/// composed form's two convolutions).
fn blur(src: &[f32], h: usize, w: usize, k: &[f32; SSIM_WINDOW]) -> Vec<f32> {
    let mut tmp = vec![0.0f32; h * w];
    for r in 0..h {
        let out = &mut tmp[r * w..(r + 1) * w];
        for (j, &kj) in k.iter().enumerate() {
            // Source row r + j − R, outside the image: zero.
            let Some(s) = (r + j).checked_sub(R).filter(|&s| s < h) else {
                continue;
            };
            for (o, &v) in out.iter_mut().zip(&src[s * w..(s + 1) * w]) {
                *o += kj * v;
            }
        }
    }
    let mut out = vec![0.0f32; h * w];
    let mut padded = vec![0.0f32; w + 2 * R];
    for r in 0..h {
        padded[R..R + w].copy_from_slice(&tmp[r * w..(r + 1) * w]);
        let row = &mut out[r * w..(r + 1) * w];
        for (j, &kj) in k.iter().enumerate() {
            for (o, &v) in row.iter_mut().zip(&padded[j..j + w]) {
                *o += kj * v;
            }
        }
    }
    out
}

/// The five blurred moments of every image: `[μp, μt, Epp, Ett, Ept]` per image.
fn moments(dims: Dims, pred: &[f32], target: &[f32], k: &[f32; SSIM_WINDOW]) -> Vec<Vec<f32>> {
    let n = dims.plane();
    (0..dims.images * 5)
        .into_par_iter()
        .map(|job| {
            let (i, which) = (job / 5, job % 5);
            let p = &pred[i * n..(i + 1) * n];
            let t = &target[i * n..(i + 1) * n];
            let product: Vec<f32> = match which {
                0 => return blur(p, dims.h, dims.w, k),
                1 => return blur(t, dims.h, dims.w, k),
                2 => p.iter().map(|v| v * v).collect(),
                3 => t.iter().map(|v| v * v).collect(),
                _ => p.iter().zip(t).map(|(a, b)| a * b).collect(),
            };
            blur(&product, dims.h, dims.w, k)
        })
        .collect()
}

/// The SSIM terms of one pixel from its five moments.
struct Pixel {
    a1: f32,
    a2: f32,
    d1: f32,
    d2: f32,
    s: f32,
}

#[inline(always)]
fn pixel(mp: f32, mt: f32, epp: f32, ett: f32, ept: f32) -> Pixel {
    let (c1, c2) = (C1 as f32, C2 as f32);
    let a1 = mp * mt * 2.0 + c1;
    let a2 = (ept - mp * mt) * 2.0 + c2;
    let d1 = mp * mp + mt * mt + c1;
    let d2 = (epp - mp * mp) + (ett - mt * mt) + c2;
    Pixel {
        a1,
        a2,
        d1,
        d2,
        s: (a1 * a2) / (d1 * d2),
    }
}

fn check(dims: Dims, pred: &[f32], target: &[f32]) {
    let len = dims.images * dims.plane();
    assert_eq!(pred.len(), len, "ssim: prediction length");
    assert_eq!(target.len(), len, "ssim: target length");
}

/// Mean SSIM over every pixel of every image (f64 sum).
pub fn ssim_mean(dims: Dims, pred: &[f32], target: &[f32]) -> f32 {
    check(dims, pred, target);
    let n = dims.plane();
    if n * dims.images == 0 {
        return f32::NAN;
    }
    let k = ssim_window();
    let m = moments(dims, pred, target, &k);
    let sum: f64 = (0..dims.images)
        .into_par_iter()
        .map(|i| {
            let [mp, mt, epp, ett, ept] = [0, 1, 2, 3, 4].map(|q| &m[5 * i + q]);
            (0..n)
                .map(|x| f64::from(pixel(mp[x], mt[x], epp[x], ett[x], ept[x]).s))
                .sum::<f64>()
        })
        .sum();
    (sum / (n * dims.images) as f64) as f32
}

/// `∂(g · ssim_mean)/∂pred`.
pub fn ssim_mean_backward(dims: Dims, pred: &[f32], target: &[f32], g: f32) -> Vec<f32> {
    check(dims, pred, target);
    let n = dims.plane();
    let mut grad = vec![0.0f32; pred.len()];
    if n * dims.images == 0 {
        return grad;
    }
    let k = ssim_window();
    let m = moments(dims, pred, target, &k);
    let w = g / (n * dims.images) as f32;
    // Per image, the coefficient maps a, b, c, then blurred.
    let coefficients: Vec<Vec<f32>> = (0..dims.images * 3)
        .into_par_iter()
        .map(|job| {
            let (i, which) = (job / 3, job % 3);
            let [mp, mt, epp, ett, ept] = [0, 1, 2, 3, 4].map(|q| &m[5 * i + q]);
            let map: Vec<f32> = (0..n)
                .map(|x| {
                    let q = pixel(mp[x], mt[x], epp[x], ett[x], ept[x]);
                    let dn = q.d1 * q.d2;
                    match which {
                        0 => {
                            w * (2.0 * mt[x] * (q.a2 - q.a1) - 2.0 * mp[x] * q.s * (q.d2 - q.d1))
                                / dn
                        }
                        1 => -w * q.s / q.d2,
                        _ => 2.0 * w * q.a1 / dn,
                    }
                })
                .collect();
            blur(&map, dims.h, dims.w, &k)
        })
        .collect();
    grad.par_chunks_mut(n).enumerate().for_each(|(i, out)| {
        let [a, b, c] = [0, 1, 2].map(|q| &coefficients[3 * i + q]);
        let p = &pred[i * n..(i + 1) * n];
        let t = &target[i * n..(i + 1) * n];
        for x in 0..n {
            out[x] = a[x] + 2.0 * p[x] * b[x] + t[x] * c[x];
        }
    });
    grad
}

#[cfg(test)]
mod tests {
    use super::super::window::SSIM_SIGMA;
    use super::*;

    /// f64 SSIM of one image by the definition (window sums over the image, zero outside), the
    /// independent truth for the kernel's value and, by central differences, its gradient.
    fn reference(h: usize, w: usize, p: &[f64], t: &[f64]) -> f64 {
        let k: Vec<f64> = {
            let c = R as f64;
            let v: Vec<f64> = (0..SSIM_WINDOW)
                .map(|i| (-((i as f64 - c).powi(2)) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp())
                .collect();
            let s: f64 = v.iter().sum();
            v.iter().map(|x| x / s).collect()
        };
        let mut total = 0.0;
        for r in 0..h as isize {
            for c in 0..w as isize {
                let mut m = [0.0f64; 5];
                for dr in -(R as isize)..=R as isize {
                    for dc in -(R as isize)..=R as isize {
                        let (rr, cc) = (r + dr, c + dc);
                        if rr < 0 || cc < 0 || rr >= h as isize || cc >= w as isize {
                            continue;
                        }
                        let kk = k[(dr + R as isize) as usize] * k[(dc + R as isize) as usize];
                        let (a, b) = (
                            p[rr as usize * w + cc as usize],
                            t[rr as usize * w + cc as usize],
                        );
                        for (q, v) in [a, b, a * a, b * b, a * b].into_iter().enumerate() {
                            m[q] += kk * v;
                        }
                    }
                }
                let [mp, mt, epp, ett, ept] = m;
                let num = (2.0 * mp * mt + C1) * (2.0 * (ept - mp * mt) + C2);
                let den = (mp * mp + mt * mt + C1) * ((epp - mp * mp) + (ett - mt * mt) + C2);
                total += num / den;
            }
        }
        total / (h * w) as f64
    }

    fn image(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let h = ((i as u32) ^ seed.wrapping_mul(0x9E37_79B9)).wrapping_mul(2654435761) >> 8;
                0.2 + 0.6 * (h as f32 / 16777216.0) + 0.2 * ((i as f32) * 0.37).sin()
            })
            .collect()
    }

    /// Value and gradient of two images (smaller than the window in one axis, larger in the
    /// other) against the f64 definition: the value to 1e-5 (f32 moments, as the composed
    /// form's), the gradient against central differences of the definition (step 1e-3, whose
    /// truncation error is ~h² ∂³S ≈ 1e-6 of the gradient's scale) to 1e-3 of its largest entry.
    #[test]
    fn value_and_gradient_match_the_definition() {
        let dims = Dims {
            images: 2,
            h: 7,
            w: 19,
        };
        let n = dims.h * dims.w;
        let p = image(2 * n, 3);
        let t = image(2 * n, 11);
        let f64s = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
        let truth = |p: &[f64], t: &[f64]| {
            (reference(dims.h, dims.w, &p[..n], &t[..n])
                + reference(dims.h, dims.w, &p[n..], &t[n..]))
                / 2.0
        };
        let (pd, td) = (f64s(&p), f64s(&t));
        let got = ssim_mean(dims, &p, &t);
        let want = truth(&pd, &td);
        assert!(
            want < 0.9,
            "the images must differ for the gradient to mean anything: {want}"
        );
        assert!((f64::from(got) - want).abs() < 1e-5, "{got} vs {want}");

        let g = 1.7f32;
        let grad = ssim_mean_backward(dims, &p, &t, g);
        let step = 1e-3;
        let fd: Vec<f64> = (0..2 * n)
            .map(|x| {
                let (mut plus, mut minus) = (pd.clone(), pd.clone());
                plus[x] += step;
                minus[x] -= step;
                f64::from(g) * (truth(&plus, &td) - truth(&minus, &td)) / (2.0 * step)
            })
            .collect();
        let scale = fd.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for x in 0..2 * n {
            let err = (f64::from(grad[x]) - fd[x]).abs();
            assert!(err <= 1e-3 * scale, "pixel {x}: {} vs {}", grad[x], fd[x]);
        }
    }
}
