//! The data term: how a rendered projection is compared with the measured one (YAML
//! `loss.data` and `loss.weighting`): the mean absolute residual (R²-Gaussian's L1), optionally
//! weighted per pixel by the photon statistics ([`count_weights`]), or each image's
//! root-mean-square residual ([`image_rms`], least squares).

use super::data::Supervision;
use crate::device::host_values;
use burn::tensor::{Tensor, TensorData};

/// Mean absolute difference.
pub fn l1(pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
    (pred - target).abs().mean()
}

/// Mean absolute difference, each pixel's weighted by `weights` (same shape).
pub fn weighted_l1(pred: Tensor<4>, target: Tensor<4>, weights: Tensor<4>) -> Tensor<1> {
    ((pred - target).abs() * weights).mean()
}

/// The root-mean-square residual of each image of `[N, C, H, W]` (each pixel's residual times
/// `weights`, same shape, when given), averaged over the `N·C` images: least squares' minimiser
/// for one image, its weight against the other loss terms set by the image's own residual level
/// (the gradient is `r / (H·W·rms)`, of L1's size). A 10⁻¹² floor under the mean square keeps the
/// gradient finite at a perfect fit.
pub fn image_rms(pred: Tensor<4>, target: Tensor<4>, weights: Option<Tensor<4>>) -> Tensor<1> {
    let mut r = pred - target;
    if let Some(w) = weights {
        r = r * w;
    }
    let [n, c, h, w] = r.dims();
    let mean_square = (r.clone() * r).reshape([n * c, h * w]).mean_dim(1);
    (mean_square + 1e-12).sqrt().mean()
}

/// The photon-statistics weights of every view of `sup` ([`DataWeighting::Counts`]): `e^{−b/2}`
/// of each pixel's line integral `b` (the normalised target divided by `factor`, the world's
/// projection factor), normalised to mean 1 over each channel's pixels in all views; a pixel
/// whose target is not finite weighs 0. One `[1, n, rows, cols]` tensor per view, on the
/// targets' device.
///
/// [`DataWeighting::Counts`]: crate::gaussians::config::DataWeighting::Counts
pub fn count_weights(sup: &Supervision, factor: f32) -> Vec<Tensor<4>> {
    // Per view, its pixels as (channel, line integral b).
    let views: Vec<Vec<(usize, f32)>> = sup
        .views
        .iter()
        .map(|v| {
            let b = host_values(&v.target);
            let channels: Vec<usize> = match &v.columns {
                Some(c) => c.list.clone(),
                None => (0..v.target.dims()[1]).collect(),
            };
            let px = b.len() / channels.len().max(1);
            b.iter()
                .enumerate()
                .map(|(i, &x)| (channels[i / px], x / factor))
                .collect()
        })
        .collect();
    // Each channel's least line integral: e^{−(b − lo)/2} ≤ 1 cannot overflow.
    let mut lo = vec![f32::INFINITY; sup.columns];
    for &(c, b) in views.iter().flatten().filter(|(_, b)| b.is_finite()) {
        lo[c] = lo[c].min(b);
    }
    let weigh = |(c, b): (usize, f32)| {
        if b.is_finite() {
            ((lo[c] - b) as f64 / 2.0).exp()
        } else {
            0.0
        }
    };
    let (mut sum, mut count) = (vec![0.0f64; sup.columns], vec![0usize; sup.columns]);
    // Summed image by image (a view's images are its channels').
    for img in views.iter().flat_map(|v| v.chunk_by(|a, b| a.0 == b.0)) {
        let c = img[0].0;
        sum[c] += img.iter().map(|&p| weigh(p)).sum::<f64>();
        count[c] += img.len();
    }
    let mean: Vec<f64> = sum
        .iter()
        .zip(&count)
        .map(|(&s, &n)| {
            let m = s / n.max(1) as f64;
            if m > 0.0 && m.is_finite() { m } else { 1.0 }
        })
        .collect();
    sup.views
        .iter()
        .zip(&views)
        .map(|(v, pixels)| {
            let w: Vec<f32> = pixels
                .iter()
                .map(|&p| (weigh(p) / mean[p.0]) as f32)
                .collect();
            Tensor::from_data(TensorData::new(w, v.target.dims()), &v.target.device())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Device;

    fn device() -> Device {
        crate::device::cpu_device()
    }

    /// Each image's root-mean-square residual, averaged over the images; its gradient is
    /// `r / (H·W·rms)` per image (L1's size), the weights scale each residual, and a perfect fit
    /// has a finite (zero) gradient.
    #[test]
    fn image_rms_is_each_images_rms_residual_averaged() {
        let ad = device().autodiff();
        // Two channels of 1 × 4 pixels: residuals (3, 0, 0, 4) → rms 2.5; (1, 1, 1, 1) → 1.
        let target = Tensor::<4>::from_data(TensorData::new(vec![0.0f32; 8], [1, 2, 1, 4]), &ad);
        let r = vec![3.0f32, 0.0, 0.0, -4.0, 1.0, -1.0, 1.0, 1.0];
        let pred =
            Tensor::<4>::from_data(TensorData::new(r.clone(), [1, 2, 1, 4]), &ad).require_grad();
        let l = image_rms(pred.clone(), target.clone(), None);
        let v: f32 = l.clone().into_scalar();
        assert!((v - 1.75).abs() < 1e-6, "{v}");
        let g = host_values(&pred.grad(&l.backward()).unwrap());
        // ∂/∂r of ½·(rms₀ + rms₁): r / (2·4·rms) per image.
        for (i, (&gi, &ri)) in g.iter().zip(&r).enumerate() {
            let rms = if i < 4 { 2.5 } else { 1.0 };
            let want = ri / (2.0 * 4.0 * rms);
            assert!((gi - want).abs() < 1e-6, "pixel {i}: {gi} vs {want}");
        }
        // Weights 2 on the first image double its residuals (rms 5).
        let w = vec![2.0f32, 2.0, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0];
        let w = Tensor::<4>::from_data(TensorData::new(w, [1, 2, 1, 4]), &ad);
        let p = Tensor::<4>::from_data(TensorData::new(r, [1, 2, 1, 4]), &ad);
        let v: f32 = image_rms(p, target.clone(), Some(w)).into_scalar();
        assert!((v - 3.0).abs() < 1e-6, "{v}");
        // A perfect fit: the loss is the floor's 10⁻⁶ and the gradient zero, not NaN.
        let exact = target.clone().require_grad();
        let l = image_rms(exact.clone(), target, None);
        let v: f32 = l.clone().into_scalar();
        assert!(v.abs() < 2e-6, "{v}");
        let g = host_values(&exact.grad(&l.backward()).unwrap());
        assert!(g.iter().all(|x| *x == 0.0), "{g:?}");
    }

    #[test]
    fn count_weights_are_inverse_noise_scales_with_mean_one_per_channel() {
        use super::super::data::{Columns, View};
        use prism_domain::geometry::Beam;
        let dev = device();
        let g = prism_domain::testing::geometry(Beam::Cone, 8, 2, 2, false);
        let f = 2.5f32;
        // `[1, n, 1, 2]` targets of line integrals `b` (normalised: b·f); channel 0 is missing
        // at the second view.
        let view = |b: &[f32], columns: Option<Vec<usize>>| View {
            camera: g.camera(0),
            target: Tensor::from_data(
                TensorData::new(b.iter().map(|x| x * f).collect(), [1, b.len() / 2, 1, 2]),
                &dev,
            ),
            columns: columns.map(|c| Columns::new(c, &dev)),
        };
        let sup = Supervision {
            views: vec![
                view(&[0.0, 2.0, 1.0, 1.0], None),
                view(&[3.0, f32::NAN], Some(vec![1])),
            ],
            columns: 2,
        };
        let w: Vec<Vec<f32>> = count_weights(&sup, f).iter().map(host_values).collect();
        // σ ∝ e^{b/2}: weights ∝ e^{−b/2}, mean 1 over each channel's pixels (the NaN weighs 0
        // and counts).
        let e = |b: f64| (-b / 2.0).exp();
        let m0 = (e(0.0) + e(2.0)) / 2.0;
        let m1 = (2.0 * e(1.0) + e(3.0)) / 4.0;
        let want = [
            vec![e(0.0) / m0, e(2.0) / m0, e(1.0) / m1, e(1.0) / m1],
            vec![e(3.0) / m1, 0.0],
        ];
        for (got, want) in w.iter().zip(&want) {
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(want) {
                assert!((*g as f64 - w).abs() < 1e-6, "{got:?} vs {want:?}");
            }
        }
        let t = sup.views[0].target.clone();
        let l: f32 =
            weighted_l1(t.clone() + 1.0, t, count_weights(&sup, f)[0].clone()).into_scalar();
        let mean = want[0].iter().sum::<f64>() / 4.0;
        assert!((l as f64 - mean).abs() < 1e-6, "{l} vs {mean}");
    }
}
