//! Differentiable training losses on Burn tensors besides the data term ([`super::data_term`]):
//! SSIM (R²-Gaussian's: 11×11 Gaussian window σ = 1.5, zero padding, C₁ = 0.01², C₂ = 0.03², on
//! raw projection values) and the total variation of a voxelized patch.

use super::ssim::window::{C1, C2, SSIM_WINDOW, ssim_window};
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Device, Tensor, TensorData};

/// The separable SSIM window as two conv2d kernels (`[1, 1, 11, 1]` and `[1, 1, 1, 11]`).
#[derive(Clone, Debug)]
pub struct SsimWindow {
    vertical: Tensor<4>,
    horizontal: Tensor<4>,
}

impl SsimWindow {
    pub fn new(device: &Device) -> Self {
        let n = SSIM_WINDOW;
        let w = ssim_window().to_vec();
        SsimWindow {
            vertical: Tensor::from_data(TensorData::new(w.clone(), [1, 1, n, 1]), device),
            horizontal: Tensor::from_data(TensorData::new(w, [1, 1, 1, n]), device),
        }
    }

    /// Zero-padded Gaussian blur of `[N, 1, H, W]`.
    fn blur(&self, x: Tensor<4>) -> Tensor<4> {
        let p = SSIM_WINDOW / 2;
        let v = conv2d(
            x,
            self.vertical.clone(),
            None,
            ConvOptions::new([1, 1], [p, 0], [1, 1], 1),
        );
        conv2d(
            v,
            self.horizontal.clone(),
            None,
            ConvOptions::new([1, 1], [0, p], [1, 1], 1),
        )
    }

    /// Mean SSIM over every image of `[N, C, H, W]` (each of the N·C images on its own); the
    /// target is data (not differentiated). One fused op on the CPU backends
    /// ([`super::ssim`]), [`SsimWindow::composed_ssim`] on wgpu.
    pub fn ssim(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        if prism_render::ops::is_gpu(&pred.device()) {
            self.composed_ssim(pred, target)
        } else {
            super::ssim::fused_ssim_mean(pred, target)
        }
    }

    /// [`SsimWindow::ssim`] composed of Burn ops (blurs as two 1-D convolutions).
    pub fn composed_ssim(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        let [n, c, h, w] = pred.dims();
        let b = n * c;
        let p = pred.reshape([b, 1, h, w]);
        let t = target.reshape([b, 1, h, w]);
        let stack = Tensor::cat(
            vec![
                p.clone(),
                t.clone(),
                p.clone() * p.clone(),
                t.clone() * t.clone(),
                p * t,
            ],
            0,
        );
        let m = self.blur(stack);
        let mu_p = m.clone().narrow(0, 0, b);
        let mu_t = m.clone().narrow(0, b, b);
        let e_pp = m.clone().narrow(0, 2 * b, b);
        let e_tt = m.clone().narrow(0, 3 * b, b);
        let e_pt = m.narrow(0, 4 * b, b);
        let mu_pp = mu_p.clone() * mu_p.clone();
        let mu_tt = mu_t.clone() * mu_t.clone();
        let mu_pt = mu_p * mu_t;
        let var_p = e_pp - mu_pp.clone();
        let var_t = e_tt - mu_tt.clone();
        let cov = e_pt - mu_pt.clone();
        let num = (mu_pt * 2.0 + C1) * (cov * 2.0 + C2);
        let den = (mu_pp + mu_tt + C1) * (var_p + var_t + C2);
        (num / den).mean()
    }
}

/// Total variation of `[M, Z, Y, X]` volumes: the mean absolute forward difference over all
/// three axes, `(Σ|Δx| + Σ|Δy| + Σ|Δz|) / (number of differences)` (R²-Gaussian's TV). One fused
/// op on the CPU backends ([`super::tv`]), [`composed_total_variation`] on wgpu.
pub fn total_variation(v: Tensor<4>) -> Tensor<1> {
    if prism_render::ops::is_gpu(&v.device()) {
        composed_total_variation(v)
    } else {
        super::tv::fused_total_variation(v)
    }
}

/// [`total_variation`] composed of Burn ops.
pub fn composed_total_variation(v: Tensor<4>) -> Tensor<1> {
    let [_, z, y, x] = v.dims();
    let count = super::tv::cpu::Dims::of(&v.dims()).differences();
    let mut sum: Option<Tensor<1>> = None;
    for (axis, n) in [(1usize, z), (2, y), (3, x)] {
        if n < 2 {
            continue;
        }
        let d = v.clone().narrow(axis, 1, n - 1) - v.clone().narrow(axis, 0, n - 1);
        let s = d.abs().sum();
        sum = Some(match sum {
            Some(acc) => acc + s,
            None => s,
        });
    }
    match sum {
        Some(s) => s / count as f64,
        None => Tensor::zeros([1], &v.device()),
    }
}

/// Directional total variation (Ehrhardt's dTV, Cueva et al.'s synergistic prior) of `[M, Z, Y, X]`
/// volumes guided by their channel mean: the mean over channels and voxels of
/// `|(I − ξξᵀ) ∇v_m|₂`, where `ξ = ∇g / √(|∇g|² + η²)`, `g` is the mean of the `M` volumes (a
/// constant: no gradient flows through the guide) and `η = eta · max|∇g|` over the patch. Forward
/// differences, over the voxels where every axis longer than one voxel has its next neighbour.
/// Where the guide is flat (`|∇g| ≪ η`) this is isotropic TV; across the guide's edges a channel's
/// gradient along `∇g` costs almost nothing, so the channels are drawn to share edges, not values.
/// `eta → ∞` is isotropic TV of each channel. With `weights` (`[M, 1, 1, 1]`), channel `m`'s
/// term is weighted by `weights[m]` (the guide stays the unweighted mean).
pub fn directional_total_variation(
    v: Tensor<4>,
    eta: f64,
    weights: Option<Tensor<4>>,
) -> Tensor<1> {
    let dims = v.dims();
    let axes: Vec<usize> = (1..4).filter(|&a| dims[a] > 1).collect();
    if axes.is_empty() {
        return Tensor::zeros([1], &v.device());
    }
    // The forward differences along `a`, cropped to the common interior of every axis.
    let forward = |t: &Tensor<4>, a: usize| {
        let mut d = t.clone().narrow(a, 1, dims[a] - 1) - t.clone().narrow(a, 0, dims[a] - 1);
        for &b in axes.iter().filter(|&&b| b != a) {
            d = d.narrow(b, 0, dims[b] - 1);
        }
        d
    };
    let guide = v.clone().detach().mean_dim(0);
    let g: Vec<Tensor<4>> = axes.iter().map(|&a| forward(&guide, a)).collect();
    let g2 = g
        .iter()
        .map(|d| d.clone().powi_scalar(2))
        .reduce(|a, b| a + b)
        .expect("an axis");
    // η² = eta² · max|∇g|²; the floor keeps a flat guide's ξ at 0, not 0/0.
    let eta2 = (g2.clone().max() * (eta * eta)).reshape([1, 1, 1, 1]) + 1e-30;
    let norm = (g2 + eta2).sqrt();
    let xi: Vec<Tensor<4>> = g.into_iter().map(|d| d / norm.clone()).collect();
    let d: Vec<Tensor<4>> = axes.iter().map(|&a| forward(&v, a)).collect();
    let along = xi
        .iter()
        .zip(&d)
        .map(|(x, d)| x.clone() * d.clone())
        .reduce(|a, b| a + b)
        .expect("an axis");
    let p2 = xi
        .into_iter()
        .zip(d)
        .map(|(x, d)| (d - x * along.clone()).powi_scalar(2))
        .reduce(|a, b| a + b)
        .expect("an axis");
    // √(p² + ε²): differentiable where a channel is flat (ε = 10⁻⁸, far below a voxel step of
    // any density the renders resolve).
    let norm = (p2 + 1e-16).sqrt();
    match weights {
        Some(w) => (norm * w).mean(),
        None => norm.mean(),
    }
}

#[cfg(test)]
mod tests {
    use super::super::tv::cpu::Dims;
    use super::*;
    use crate::device::host_values;
    use ndarray::Array2;
    use prism_domain::metrics::{SsimParams, ssim_2d};

    fn device() -> Device {
        crate::device::cpu_device()
    }

    fn image(h: usize, w: usize, seed: u32) -> Vec<f32> {
        (0..h * w)
            .map(|i| {
                let (r, c) = ((i / w) as f32, (i % w) as f32);
                let n = ((i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8) as f32
                    / 16777216.0;
                0.5 + 0.4 * (0.3 * r).sin() * (0.2 * c).cos() + 0.1 * n
            })
            .collect()
    }

    #[test]
    fn ssim_matches_the_host_metric_and_its_gradient_matches_finite_differences() {
        let (h, w) = (17, 23);
        let a = image(h, w, 1);
        let b = image(h, w, 7);
        let dev = device();
        let win = SsimWindow::new(&dev);
        let ta = Tensor::<4>::from_data(TensorData::new(a.clone(), [1, 1, h, w]), &dev);
        let tb = Tensor::<4>::from_data(TensorData::new(b.clone(), [1, 1, h, w]), &dev);
        let got: f32 = win.ssim(ta, tb).into_scalar();
        // Independent truth: the host metric (f64, zero-padded window, data range 1).
        let host = ssim_2d(
            Array2::from_shape_vec((h, w), a.clone()).unwrap().view(),
            Array2::from_shape_vec((h, w), b.clone()).unwrap().view(),
            &SsimParams::default(),
        )
        .unwrap();
        assert!((got as f64 - host).abs() < 2e-5, "{got} vs {host}");

        // Gradient w.r.t. the prediction vs central differences of the host metric.
        let ad = dev.clone().autodiff();
        let pa =
            Tensor::<4>::from_data(TensorData::new(a.clone(), [1, 1, h, w]), &ad).require_grad();
        let tb = Tensor::<4>::from_data(TensorData::new(b.clone(), [1, 1, h, w]), &ad);
        let grads = win.ssim(pa.clone(), tb).backward();
        let g: Vec<f32> = pa
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let eps = 1e-3f32;
        for &i in &[0usize, 5, 40, 200, h * w - 1] {
            let mut plus = a.clone();
            let mut minus = a.clone();
            plus[i] += eps;
            minus[i] -= eps;
            let f = |v: Vec<f32>| {
                ssim_2d(
                    Array2::from_shape_vec((h, w), v).unwrap().view(),
                    Array2::from_shape_vec((h, w), b.clone()).unwrap().view(),
                    &SsimParams::default(),
                )
                .unwrap()
            };
            let fd = (f(plus) - f(minus)) / (2.0 * eps as f64);
            assert!(
                (g[i] as f64 - fd).abs() < 1e-4 * fd.abs().max(1e-2),
                "pixel {i}: autodiff {} vs finite difference {fd}",
                g[i]
            );
        }
    }

    /// The fused op (CPU backends) and the composed form (wgpu) agree in value and gradient
    /// on a batch of `[2, 3, 13, 29]` images, to f32 rounding of their different sum orders.
    #[test]
    fn fused_ssim_matches_the_composed_form_and_its_gradient() {
        let (n, c, h, w) = (2, 3, 13, 29);
        let ad = device().autodiff();
        let win = SsimWindow::new(&ad);
        let len = n * c * h * w;
        let p = image(1, len, 5);
        let t: Vec<f32> = image(1, len, 9).iter().rev().map(|v| 1.2 - v).collect();
        let leaf = |v: &[f32]| {
            Tensor::<4>::from_data(TensorData::new(v.to_vec(), [n, c, h, w]), &ad).require_grad()
        };
        let target = Tensor::<4>::from_data(TensorData::new(t, [n, c, h, w]), &ad);
        let (pf, pc) = (leaf(&p), leaf(&p));
        let fused = win.ssim(pf.clone(), target.clone());
        let composed = win.composed_ssim(pc.clone(), target);
        let (vf, vc): (f32, f32) = (fused.clone().into_scalar(), composed.clone().into_scalar());
        assert!(vc < 0.9 && (vf - vc).abs() < 1e-5, "{vf} vs {vc}");
        let gf = host_values(&pf.grad(&fused.backward()).unwrap());
        let gc = host_values(&pc.grad(&composed.backward()).unwrap());
        let scale = gc.iter().fold(0.0f32, |a, v| a.max(v.abs()));
        for (a, b) in gf.iter().zip(&gc) {
            assert!((a - b).abs() <= 1e-4 * scale, "{a} vs {b} (scale {scale})");
        }
    }

    /// The fused op (CPU backends) and the composed form (wgpu) agree in value (f32 sums in
    /// another order) and gradient (sums of ±g/n, one rounding apart at most), on volumes with
    /// ties (equal neighbours: sign 0) and one- and two-voxel axes.
    #[test]
    fn fused_total_variation_matches_the_composed_form_and_its_gradient() {
        let ad = device().autodiff();
        for shape in [[2, 3, 5, 7], [1, 1, 4, 9], [3, 2, 1, 2]] {
            let len: usize = shape.iter().product();
            // Values on a coarse lattice, so many neighbours are equal.
            let v: Vec<f32> = image(1, len, 3).iter().map(|x| (x * 8.0).round()).collect();
            let leaf =
                || Tensor::<4>::from_data(TensorData::new(v.clone(), shape), &ad).require_grad();
            let (vf, vc) = (leaf(), leaf());
            let fused = total_variation(vf.clone()) * 0.7;
            let composed = composed_total_variation(vc.clone()) * 0.7;
            let (a, b): (f32, f32) = (fused.clone().into_scalar(), composed.clone().into_scalar());
            assert!((a - b).abs() <= 1e-6 * b.abs(), "{shape:?}: {a} vs {b}");
            let gf = host_values(&vf.grad(&fused.backward()).unwrap());
            let gc = host_values(&vc.grad(&composed.backward()).unwrap());
            let unit = 0.7 / Dims::of(&shape).differences().max(1) as f32;
            for (x, y) in gf.iter().zip(&gc) {
                assert!((x - y).abs() <= 1e-6 * unit, "{shape:?}: {x} vs {y}");
            }
            assert!(gc.iter().any(|g| *g != 0.0), "{shape:?}: a zero gradient");
        }
    }

    #[test]
    fn total_variation_is_the_mean_absolute_forward_difference() {
        let dev = device();
        // v = x + 2y + 3z on a 2×3×4×5 grid: |Δx| = 1, |Δy| = 2, |Δz| = 3 everywhere.
        let (m, z, y, x) = (2, 3, 4, 5);
        let data: Vec<f32> = (0..m * z * y * x)
            .map(|i| {
                let (xi, yi, zi) = (i % x, (i / x) % y, (i / (x * y)) % z);
                (xi + 2 * yi + 3 * zi) as f32
            })
            .collect();
        let v = Tensor::<4>::from_data(TensorData::new(data, [m, z, y, x]), &dev);
        let tv: f32 = total_variation(v).into_scalar();
        let (nx, ny, nz) = (
            m * z * y * (x - 1),
            m * z * (y - 1) * x,
            m * (z - 1) * y * x,
        );
        let want = (nx + 2 * ny + 3 * nz) as f32 / (nx + ny + nz) as f32;
        assert!((tv - want).abs() < 1e-6, "{tv} vs {want}");
    }

    /// Isotropic TV by hand: the mean over the cropped interior of `√(Σ_axes Δ²)`.
    fn isotropic_tv(data: &[f32], [m, z, y, x]: [usize; 4]) -> f64 {
        let at =
            |c: usize, k: usize, j: usize, i: usize| data[((c * z + k) * y + j) * x + i] as f64;
        let (zs, ys, xs) = ((z - 1).max(1), (y - 1).max(1), (x - 1).max(1));
        let mut sum = 0.0;
        for c in 0..m {
            for k in 0..zs {
                for j in 0..ys {
                    for i in 0..xs {
                        let here = at(c, k, j, i);
                        let mut s2 = 0.0;
                        if x > 1 {
                            s2 += (at(c, k, j, i + 1) - here).powi(2);
                        }
                        if y > 1 {
                            s2 += (at(c, k, j + 1, i) - here).powi(2);
                        }
                        if z > 1 {
                            s2 += (at(c, k + 1, j, i) - here).powi(2);
                        }
                        sum += (s2 + 1e-16).sqrt();
                    }
                }
            }
        }
        sum / (m * zs * ys * xs) as f64
    }

    #[test]
    fn directional_tv_with_a_flat_guide_or_a_huge_eta_is_isotropic_tv() {
        let dev = device();
        for dims in [[2usize, 3, 4, 5], [3, 1, 6, 7]] {
            let n: usize = dims.iter().product();
            let data = image(1, n, 3);
            let v = Tensor::<4>::from_data(TensorData::new(data.clone(), dims), &dev);
            let got: f32 = directional_total_variation(v, 1e6, None).into_scalar();
            let want = isotropic_tv(&data, dims);
            assert!(
                (got as f64 - want).abs() < 1e-5 * want,
                "{dims:?}: {got} vs {want}"
            );
        }
        // Two channels that are each other's negative: a zero guide, so ξ = 0 at any η.
        let dims = [2usize, 1, 5, 6];
        let half: Vec<f32> = (0..30).map(|i| ((i * 7) % 11) as f32).collect();
        let data: Vec<f32> = half
            .iter()
            .copied()
            .chain(half.iter().map(|a| -a))
            .collect();
        let v = Tensor::<4>::from_data(TensorData::new(data.clone(), dims), &dev);
        let got: f32 = directional_total_variation(v, 0.01, None).into_scalar();
        let want = isotropic_tv(&data, dims);
        assert!((got as f64 - want).abs() < 1e-5 * want, "{got} vs {want}");
    }

    #[test]
    fn directional_tv_of_ramps_is_each_channels_gradient_less_its_part_along_the_guides() {
        let dev = device();
        // Three channels with uniform gradients (∂x, ∂y) on a 5×6 slice: the guide's gradient is
        // their mean G everywhere, η = eta·|G|, ξ = G/(|G|·√(1 + eta²)), and each channel costs
        // |d − ξ(ξ·d)| at every pixel.
        let grads = [[1.0f64, 0.0], [1.0, 2.0], [-2.0, 1.0]];
        let (y, x) = (5usize, 6usize);
        let data: Vec<f32> = grads
            .iter()
            .flat_map(|[gx, gy]| {
                (0..y * x).map(move |p| (gx * (p % x) as f64 + gy * (p / x) as f64) as f32)
            })
            .collect();
        let g = [
            grads.iter().map(|d| d[0]).sum::<f64>() / 3.0,
            grads.iter().map(|d| d[1]).sum::<f64>() / 3.0,
        ];
        // Channel weights scale each channel's cost; the guide stays the unweighted mean.
        for (eta, w) in [
            (0.1f64, None),
            (1.0, None),
            (3.0, None),
            (0.1, Some([0.5f64, 1.0, 3.0])),
        ] {
            let norm = (g[0] * g[0] + g[1] * g[1]).sqrt() * (1.0 + eta * eta).sqrt();
            let xi = [g[0] / norm, g[1] / norm];
            let want = grads
                .iter()
                .zip(w.unwrap_or([1.0; 3]))
                .map(|(d, w)| {
                    let along = xi[0] * d[0] + xi[1] * d[1];
                    let p = [d[0] - xi[0] * along, d[1] - xi[1] * along];
                    w * (p[0] * p[0] + p[1] * p[1]).sqrt()
                })
                .sum::<f64>()
                / 3.0;
            let v = Tensor::<4>::from_data(TensorData::new(data.clone(), [3, 1, y, x]), &dev);
            let weights = w.map(|w| {
                let w: Vec<f32> = w.iter().map(|&a| a as f32).collect();
                Tensor::<4>::from_data(TensorData::new(w, [3, 1, 1, 1]), &dev)
            });
            let got: f32 = directional_total_variation(v, eta, weights).into_scalar();
            assert!(
                (got as f64 - want).abs() < 1e-5 * want,
                "η {eta}, weights {w:?}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn directional_tv_spares_an_edge_the_guide_has() {
        let dev = device();
        // Both channels step at x = 3 (heights 1 and 2): on the edge ξ = ĝ/√(1 + eta²), so each
        // channel keeps the share 1 − |ξ|² = eta²/(1 + eta²) of its jump (here 10⁻⁴).
        let (y, x) = (6usize, 8usize);
        let step = |h: f32| (0..y * x).map(move |i| if i % x >= 3 { h } else { 0.0 });
        let dims = [2usize, 1, y, x];
        let data: Vec<f32> = step(1.0).chain(step(2.0)).collect();
        let v = Tensor::<4>::from_data(TensorData::new(data.clone(), dims), &dev);
        let got: f32 = directional_total_variation(v, 0.01, None).into_scalar();
        let want = isotropic_tv(&data, dims) * 1e-4 / (1.0 + 1e-4);
        // f32: 1 − |ξ|² ≈ 10⁻⁴ is a difference of numbers near 1 (relative error ~10⁻³).
        assert!((got as f64 - want).abs() < 1e-2 * want, "{got} vs {want}");
    }
}
