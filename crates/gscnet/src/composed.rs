//! The fused spectral kernels composed from Burn tensor ops: the path for backends without a
//! fused kernel (wgpu), differentiated by Burn's autodiff. Same maths as [`crate::cpu::scan`]
//! and [`crate::cpu::conv`]; the tests below check the two paths agree on the CPU.

use burn::tensor::{Tensor, activation};

use crate::cpu::activation::Activation;

/// Whether `device` has the fused CPU kernels (Flex, NdArray, with or without autodiff).
pub fn has_fused_kernels(device: &burn::tensor::Device) -> bool {
    #[cfg(feature = "wgpu")]
    {
        !matches!(
            device.clone().inner().as_dispatch(),
            burn::backend::DispatchDevice::Cube(_)
        )
    }
    #[cfg(not(feature = "wgpu"))]
    {
        let _ = device;
        true
    }
}

/// The selective scan of [`crate::ssm`] as a loop over the M spectral steps: the states
/// `h_m = exp(Δ_m A) ⊙ h_{m−1} + (Δ_m x_m) B_m` are `[K, E, N]` tensors.
pub fn selective_scan(
    x: Tensor<3>,
    delta: Tensor<3>,
    a_log: Tensor<2>,
    b: Tensor<3>,
    c: Tensor<3>,
    d: Tensor<1>,
    softplus: bool,
) -> Tensor<3> {
    let [k, m, e] = x.dims();
    let [_, n] = a_log.dims();
    let delta = if softplus {
        activation::softplus(delta, 1.0)
    } else {
        delta
    };
    let a = a_log.exp().neg().reshape([1, e, n]);
    let d = d.reshape([1, e]);
    let mut h = Tensor::<3>::zeros([k, e, n], &x.device());
    let mut ys = Vec::with_capacity(m);
    for step in 0..m {
        let xm = x.clone().narrow(1, step, 1).reshape([k, e]);
        let dm = delta.clone().narrow(1, step, 1).reshape([k, e]);
        let bm = b.clone().narrow(1, step, 1).reshape([k, 1, n]);
        let cm = c.clone().narrow(1, step, 1).reshape([k, 1, n]);
        let decay = (dm.clone().reshape([k, e, 1]) * a.clone()).exp();
        h = decay * h + (dm * xm.clone()).reshape([k, e, 1]) * bm;
        let y = (h.clone() * cm).sum_dim(2).reshape([k, e]) + d.clone() * xm;
        ys.push(y.reshape([k, 1, e]));
    }
    Tensor::cat(ys, 1)
}

/// [`crate::ops::activate`] composed of Burn ops.
pub fn activate<const D: usize>(x: Tensor<D>, kind: Activation) -> Tensor<D> {
    match kind {
        Activation::Silu => activation::silu(x),
        Activation::Softplus => x.clone().clamp_min(0.0) + x.abs().neg().exp().log1p(),
        Activation::Sigmoid { lo, span } => activation::sigmoid(x) * span + lo,
    }
}

/// SiLU of the centred depthwise convolution over M of [`crate::conv`]:
/// `p_{k,m,e} = bias_e + Σ_j w_{e,j} u_{k, m+j−r, e}` with zero padding.
pub fn conv_silu(u: Tensor<3>, w: Tensor<2>, bias: Tensor<1>) -> Tensor<3> {
    let [k, m, e] = u.dims();
    let [_, taps] = w.dims();
    let r = taps / 2;
    let device = u.device();
    let padded = if r > 0 {
        let pad = Tensor::<3>::zeros([k, r, e], &device);
        Tensor::cat(vec![pad.clone(), u, pad], 1)
    } else {
        u
    };
    let mut p = bias.reshape([1, 1, e]).expand([k, m, e]);
    for j in 0..taps {
        let tap = w.clone().narrow(1, j, 1).reshape([1, 1, e]);
        p = p + padded.clone().narrow(1, j, m) * tap;
    }
    activation::silu(p)
}

/// [`crate::ops::table_lookup`] composed of Burn ops: the table's four rows around each û
/// gathered and blended with Keys' weights ([`crate::cpu::table`]).
pub fn table_lookup(table: Tensor<2>, u: Tensor<1>, h: f32) -> Tensor<2> {
    let [rows, _] = table.dims();
    let pos = u.add_scalar(1.0).div_scalar(h);
    let lower = pos.clone().floor().clamp(0.0, (rows - 4) as f32).detach();
    let s = pos.sub(lower.clone());
    let s2 = s.clone().mul(s.clone());
    let s3 = s2.clone().mul(s.clone());
    let weights = [
        s3.clone()
            .neg()
            .add(s2.clone().mul_scalar(2.0))
            .sub(s.clone()),
        s3.clone()
            .mul_scalar(3.0)
            .sub(s2.clone().mul_scalar(5.0))
            .add_scalar(2.0),
        s3.clone()
            .mul_scalar(-3.0)
            .add(s2.clone().mul_scalar(4.0))
            .add(s),
        s3.sub(s2),
    ];
    let lower = lower.int();
    weights
        .into_iter()
        .enumerate()
        .map(|(j, w)| {
            let rows = table.clone().select(0, lower.clone().add_scalar(j as i64));
            rows.mul(w.unsqueeze_dim::<2>(1))
        })
        .reduce(|a, b| a.add(b))
        .expect("four rows")
        .mul_scalar(0.5)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    fn device() -> Device {
        crate::test_util::cpu().autodiff()
    }

    fn tensor<const D: usize>(dims: [usize; D], seed: u32, lo: f32, hi: f32) -> Tensor<D> {
        let n: usize = dims.iter().product();
        let v: Vec<f32> = (0..n)
            .map(|i| {
                let h = (i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8;
                lo + (hi - lo) * (h as f32 / 16777216.0)
            })
            .collect();
        Tensor::from_data(TensorData::new(v, dims), &device()).require_grad()
    }

    fn vec_of<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap()
    }

    fn close(what: &str, a: Vec<f32>, b: Vec<f32>) {
        let scale = b.iter().fold(0.0f32, |s, v| s.max(v.abs())).max(1e-20);
        let err = a
            .iter()
            .zip(&b)
            .fold(0.0f32, |s, (x, y)| s.max((x - y).abs()));
        assert!(err <= 2e-5 * scale, "{what}: {:e}", err / scale);
    }

    #[test]
    fn composed_scan_matches_the_fused_kernel_and_its_gradients() {
        let (k, m, e, n) = (5, 4, 3, 2);
        for softplus in [false, true] {
            let x = tensor([k, m, e], 1, -1.0, 1.0);
            let dt = tensor([k, m, e], 2, 0.05, 0.8);
            let a_log = tensor([e, n], 3, -1.0, 1.0);
            let b = tensor([k, m, n], 4, -1.0, 1.0);
            let c = tensor([k, m, n], 5, -1.0, 1.0);
            let d = tensor([e], 6, -1.0, 1.0);
            let w = tensor([k, m, e], 7, -1.0, 1.0);
            let args = (
                x.clone(),
                dt.clone(),
                a_log.clone(),
                b.clone(),
                c.clone(),
                d.clone(),
            );
            let fused = crate::ops::fused_selective_scan(
                args.0, args.1, args.2, args.3, args.4, args.5, softplus,
            );
            let composed = selective_scan(
                x.clone(),
                dt.clone(),
                a_log.clone(),
                b.clone(),
                c.clone(),
                d.clone(),
                softplus,
            );
            close("scan", vec_of(composed.clone()), vec_of(fused.clone()));
            let gf = (fused * w.clone()).sum().backward();
            let gc = (composed * w).sum().backward();
            for (name, t) in [("x", &x), ("dt", &dt), ("b", &b), ("c", &c)] {
                close(
                    name,
                    vec_of(t.grad(&gc).unwrap()),
                    vec_of(t.grad(&gf).unwrap()),
                );
            }
            close(
                "a_log",
                vec_of(a_log.grad(&gc).unwrap()),
                vec_of(a_log.grad(&gf).unwrap()),
            );
            close(
                "d",
                vec_of(d.grad(&gc).unwrap()),
                vec_of(d.grad(&gf).unwrap()),
            );
        }
    }

    #[test]
    fn composed_conv_matches_the_fused_kernel_and_its_gradients() {
        let (k, m, e) = (4, 5, 3);
        for taps in [1, 3, 5] {
            let u = tensor([k, m, e], 11, -1.0, 1.0);
            let w = tensor([e, taps], 12, -1.0, 1.0);
            let bias = tensor([e], 13, -0.5, 0.5);
            let g = tensor([k, m, e], 14, -1.0, 1.0);
            let fused = crate::ops::fused_conv_silu(u.clone(), w.clone(), bias.clone());
            let composed = conv_silu(u.clone(), w.clone(), bias.clone());
            close("conv", vec_of(composed.clone()), vec_of(fused.clone()));
            let gf = (fused * g.clone()).sum().backward();
            let gc = (composed * g).sum().backward();
            close(
                "u",
                vec_of(u.grad(&gc).unwrap()),
                vec_of(u.grad(&gf).unwrap()),
            );
            close(
                "w",
                vec_of(w.grad(&gc).unwrap()),
                vec_of(w.grad(&gf).unwrap()),
            );
            close(
                "bias",
                vec_of(bias.grad(&gc).unwrap()),
                vec_of(bias.grad(&gf).unwrap()),
            );
        }
    }

    /// The fused cubic table lookup against its composed form in value and gradients (table
    /// and û), with û over all of [−1, 1] and both ends.
    #[test]
    fn composed_table_lookup_matches_the_fused_kernel_and_its_gradients() {
        let (t, m, k) = (9, 3, 41);
        let h = 2.0 / (t - 1) as f32;
        let table = tensor([t + 2, m], 31, -1.0, 1.0);
        let v: Vec<f32> = (0..k)
            .map(|i| -1.0 + 2.0 * i as f32 / (k - 1) as f32)
            .collect();
        let u = Tensor::<1>::from_data(TensorData::new(v, [k]), &device()).require_grad();
        let g = tensor([k, m], 32, -1.0, 1.0);
        let fused = crate::ops::table_lookup(table.clone(), u.clone(), h);
        let composed = table_lookup(table.clone(), u.clone(), h);
        close("lookup", vec_of(composed.clone()), vec_of(fused.clone()));
        let gf = (fused * g.clone()).sum().backward();
        let gc = (composed * g).sum().backward();
        close(
            "table",
            vec_of(table.grad(&gc).unwrap()),
            vec_of(table.grad(&gf).unwrap()),
        );
        close(
            "u",
            vec_of(u.grad(&gc).unwrap()),
            vec_of(u.grad(&gf).unwrap()),
        );
    }

    /// The fused SiLU against Burn's composed one (a sigmoid and a product) and its gradient,
    /// on a 3-D tensor over [−12, 12] (both tails of σ).
    #[test]
    fn composed_silu_matches_the_fused_kernel_and_its_gradient() {
        let x = tensor([6, 3, 7], 21, -12.0, 12.0);
        let g = tensor([6, 3, 7], 22, -1.0, 1.0);
        let fused = crate::ops::silu(x.clone());
        let composed = activation::silu(x.clone());
        close("silu", vec_of(composed.clone()), vec_of(fused.clone()));
        let gf = (fused * g.clone()).sum().backward();
        let gc = (composed * g).sum().backward();
        close(
            "x",
            vec_of(x.grad(&gc).unwrap()),
            vec_of(x.grad(&gf).unwrap()),
        );
    }

    /// The fused density softplus and scale sigmoid against their composed forms (wgpu's) in
    /// value and gradient, on `[5, 7]` values over [−30, 30].
    #[test]
    fn composed_gaussian_activations_match_the_fused_kernel_and_their_gradients() {
        let ad = device();
        let v: Vec<f32> = (0..35)
            .map(|i| -30.0 + 60.0 * (i as f32 / 34.0).powi(3))
            .collect();
        let g: Vec<f32> = (0..35).map(|i| ((i * 7) % 11) as f32 / 5.0 - 1.0).collect();
        let leaf =
            || Tensor::<2>::from_data(TensorData::new(v.clone(), [5, 7]), &ad).require_grad();
        let up = Tensor::<2>::from_data(TensorData::new(g, [5, 7]), &ad);
        for kind in [
            Activation::Softplus,
            Activation::Sigmoid {
                lo: 0.01,
                span: 0.49,
            },
        ] {
            let (xf, xc) = (leaf(), leaf());
            let (yf, yc) = (
                crate::ops::activate(xf.clone(), kind),
                activate(xc.clone(), kind),
            );
            // Values to 2e-6 relative. The composed sigmoid's gradient σ(1 − σ) loses ulp(σ) to
            // cancellation in 1 − σ, an absolute error ≲ span·6e-8·|ḡ|, so gradients are held
            // to 1e-6 of their largest entry.
            let close = |a: &[f32], b: &[f32], what: &str| {
                let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                for (p, q) in a.iter().zip(b) {
                    let tol = if what == "value" {
                        2e-6 * q.abs().max(1e-3)
                    } else {
                        1e-6 * scale
                    };
                    assert!((p - q).abs() <= tol, "{kind:?} {what}: {p} vs {q}");
                }
            };
            close(&vec_of(yf.clone()), &vec_of(yc.clone()), "value");
            let gf = xf.grad(&(yf * up.clone()).sum().backward()).unwrap();
            let gc = xc.grad(&(yc * up.clone()).sum().backward()).unwrap();
            close(&vec_of(gf), &vec_of(gc), "gradient");
        }
    }
}
