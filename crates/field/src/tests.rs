//! The op through Burn: autodiff gradients against the CPU kernel and finite differences,
//! CPU–wgpu parity (feature `wgpu`, lavapipe in CI), and a tiny fit.

use crate::cpu;
use crate::grid::{HashGrid, HashGridConfig};
use crate::ops::encode;
use crate::{FieldConfig, NeuralField};
use burn::tensor::{Device, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn cpu_device() -> Device {
    #[cfg(feature = "flex")]
    {
        Device::flex()
    }
    #[cfg(all(feature = "ndarray", not(feature = "flex")))]
    #[allow(deprecated)]
    {
        Device::ndarray()
    }
}

fn grid() -> HashGrid {
    HashGridConfig {
        levels: 5,
        features: 2,
        base_resolution: 4,
        growth: 1.6,
        log2_table_size: 8,
    }
    .layout()
}

/// `n` values uniform in `[lo, hi)`, seeded.
pub(crate) fn random(n: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

fn tensor(values: Vec<f32>, shape: [usize; 2], device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(values, shape), device)
}

fn values(t: Tensor<2>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

#[test]
fn autodiff_gives_the_kernels_scatter_and_finite_differences_agree() {
    let g = grid();
    let device = cpu_device().autodiff();
    let n = 64;
    let pts = random(3 * n, 0.0, 1.0, 1);
    let tab = random(g.parameters(), -1.0, 1.0, 2);
    let weights = random(n * g.width(), -1.0, 1.0, 3);
    let table = tensor(tab.clone(), [g.rows(), g.features], &device).require_grad();
    let points = tensor(pts.clone(), [n, 3], &device);
    let w = tensor(weights.clone(), [n, g.width()], &device);
    let enc = encode(points, table.clone(), &g).unwrap();
    assert_eq!(values(enc.clone().inner()), cpu::encode(&g, &pts, &tab));
    // L = Σ w·enc²: dL/denc = 2 w enc, chained through the op's backward.
    let loss = (enc.clone() * enc * w).sum();
    let grads = loss.backward();
    let got = values(table.grad(&grads).unwrap());
    let enc_host = cpu::encode(&g, &pts, &tab);
    let upstream: Vec<f32> = enc_host
        .iter()
        .zip(&weights)
        .map(|(e, w)| 2.0 * e * w)
        .collect();
    let want = cpu::encode_backward(&g, &pts, &upstream);
    for (a, b) in got.iter().zip(&want) {
        assert!((a - b).abs() <= 1e-5 * b.abs().max(1.0), "{a} vs {b}");
    }
    // Central differences of L in f64 on the host, a few rows.
    let loss_at = |t: &[f32]| -> f64 {
        cpu::encode(&g, &pts, t)
            .iter()
            .zip(&weights)
            .map(|(e, w)| *w as f64 * (*e as f64).powi(2))
            .sum()
    };
    let h = 1e-2;
    for r in (0..tab.len()).step_by(13) {
        let (mut up, mut down) = (tab.clone(), tab.clone());
        up[r] += h;
        down[r] -= h;
        let fd = (loss_at(&up) - loss_at(&down)) / (2.0 * h as f64);
        assert!(
            (fd - got[r] as f64).abs() < 5e-3 * fd.abs().max(1.0),
            "row {r}: {fd} vs {}",
            got[r]
        );
    }
}

#[test]
fn shapes_and_dtypes_are_checked_with_the_argument_named() {
    let g = grid();
    let d = cpu_device();
    let table = Tensor::<2>::zeros([g.rows(), g.features], &d);
    let e = encode(Tensor::<2>::zeros([4, 2], &d), table, &g).unwrap_err();
    assert!(e.to_string().starts_with("points"), "{e}");
    let e = encode(
        Tensor::<2>::zeros([4, 3], &d),
        Tensor::<2>::zeros([3, 2], &d),
        &g,
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("table"), "{e}");
}

/// A tiny field learns a smooth function of position (the op, the MLP and Adam together).
#[test]
fn a_field_fits_a_smooth_function() {
    use burn::optim::{AdamConfig, GradientsParams};
    let device = cpu_device().autodiff();
    let config = FieldConfig {
        hash_grid: HashGridConfig {
            levels: 6,
            base_resolution: 4,
            growth: 1.5,
            log2_table_size: 12,
            ..Default::default()
        },
        width: 16,
        ..Default::default()
    };
    let mut field: NeuralField = config.init(0, &device).unwrap();
    let mut optim = AdamConfig::new().init();
    let target = |p: &[f32]| {
        0.2 + 0.6
            * (-(((p[0] - 0.5).powi(2) + (p[1] - 0.4).powi(2) + (p[2] - 0.6).powi(2)) / 0.05)).exp()
    };
    let n = 512;
    let eval_pts = random(3 * n, 0.0, 1.0, 99);
    let eval_want: Vec<f32> = eval_pts.chunks(3).map(target).collect();
    let mse = |f: &NeuralField| -> f32 {
        let got = f
            .forward(tensor(eval_pts.clone(), [n, 3], &device))
            .unwrap();
        let got = got.into_data().try_to_vec::<f32>().unwrap();
        got.iter()
            .zip(&eval_want)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f32>()
            / n as f32
    };
    let before = mse(&field);
    for it in 0..150 {
        let pts = random(3 * n, 0.0, 1.0, it);
        let want: Vec<f32> = pts.chunks(3).map(target).collect();
        let pred = field.forward(tensor(pts, [n, 3], &device)).unwrap();
        let want = Tensor::<1>::from_data(TensorData::new(want, [n]), &device);
        let loss = (pred - want).powi_scalar(2).mean();
        let grads = GradientsParams::from_grads(loss.backward(), &field);
        field = optim.step(1e-2, field, grads);
    }
    let after = mse(&field);
    assert!(
        after < 0.05 * before && after < 5e-4,
        "MSE {before} → {after}"
    );
}

/// The CubeCL kernels against the CPU kernels, forward and backward.
#[cfg(feature = "wgpu")]
#[test]
fn wgpu_matches_the_cpu() {
    let g = HashGridConfig {
        levels: 6,
        features: 2,
        base_resolution: 4,
        growth: 1.7,
        log2_table_size: 9,
    }
    .layout();
    assert!(g.levels.iter().any(|l| l.dense) && g.levels.iter().any(|l| !l.dense));
    let gpu = Device::wgpu(burn::tensor::DeviceKind::DefaultDevice).autodiff();
    let n = 777;
    let mut pts = random(3 * n, -0.05, 1.05, 4);
    pts[0] = f32::NAN;
    pts[4] = f32::INFINITY;
    let tab = random(g.parameters(), -1.0, 1.0, 5);
    let up = random(n * g.width(), -1.0, 1.0, 6);
    let table = tensor(tab.clone(), [g.rows(), g.features], &gpu).require_grad();
    let enc = encode(tensor(pts.clone(), [n, 3], &gpu), table.clone(), &g).unwrap();
    let got = values(enc.clone().inner());
    let want = cpu::encode(&g, &pts, &tab);
    for (i, (a, b)) in got.iter().zip(&want).enumerate() {
        assert!((a - b).abs() < 1e-5, "encoding {i}: {a} vs {b}");
    }
    let grads = (enc * tensor(up.clone(), [n, g.width()], &gpu))
        .sum()
        .backward();
    let got = values(table.grad(&grads).unwrap());
    let want = cpu::encode_backward(&g, &pts, &up);
    for (i, (a, b)) in got.iter().zip(&want).enumerate() {
        assert!(
            (a - b).abs() < 1e-4 * b.abs().max(1.0),
            "table row {i}: {a} vs {b}"
        );
    }
}

/// The MLP as Burn's own layers compose it (NAF's definition): the reference of the fused op.
fn decode_by_layers(field: &NeuralField, enc: Tensor<2>) -> Tensor<2> {
    use burn::tensor::activation::leaky_relu;
    let layout = field.layout();
    let mut x = enc.clone();
    for (l, layer) in field.layers.iter().enumerate() {
        if l == layout.skip {
            x = Tensor::cat(vec![x, enc.clone()], 1);
        }
        x = layer.forward(x);
        if l + 1 < field.layers.len() {
            x = leaky_relu(x, layout.slope as f64);
        }
    }
    x
}

/// Values and gradients (every layer's weight and bias, the encodings) of `decode` on `device`
/// against Burn's layers on the same device.
fn check_decode_against_layers(device: &Device, tolerance: f32) {
    let config = FieldConfig {
        hash_grid: HashGridConfig {
            levels: 3,
            features: 2,
            base_resolution: 4,
            growth: 1.5,
            log2_table_size: 6,
        },
        width: 7,
        layers: 4,
        skip: 2,
        table_lr_scale: 1.0,
    };
    let field = config.init(3, device).unwrap();
    let width = field.grid().width();
    // More points than a CPU task (512), so tasks are split and joined.
    let n = 1100;
    let enc_values = random(n * width, -1.0, 1.0, 21);
    let up = tensor(random(n, -1.0, 1.0, 22), [n, 1], device);
    let run = |fused: bool| {
        let enc = tensor(enc_values.clone(), [n, width], device).require_grad();
        let out = if fused {
            field.decode(enc.clone()).unwrap()
        } else {
            decode_by_layers(&field, enc.clone())
        };
        let grads = (out.clone() * up.clone()).sum().backward();
        let mut g = vec![values(out), values(enc.grad(&grads).unwrap())];
        for layer in &field.layers {
            g.push(values(layer.weight.grad(&grads).unwrap()));
            let b = layer.bias.as_ref().unwrap().grad(&grads).unwrap();
            g.push(b.into_data().try_to_vec::<f32>().unwrap());
        }
        g
    };
    let (got, want) = (run(true), run(false));
    let names = ["outputs", "encodings' gradient"];
    for (k, (a, b)) in got.iter().zip(&want).enumerate() {
        assert_eq!(a.len(), b.len());
        let what = names
            .get(k)
            .map_or_else(|| format!("parameter {}", k - 2), |s| s.to_string());
        let scale = b.iter().fold(1f32, |m, v| m.max(v.abs()));
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!((x - y).abs() <= tolerance * scale, "{what} {i}: {x} vs {y}");
        }
    }
}

#[test]
fn the_fused_mlp_matches_burns_layers_and_their_gradients() {
    // The same sums in another order (f32): 1e-5 of the largest value.
    check_decode_against_layers(&cpu_device().autodiff(), 1e-5);
}

/// On wgpu the MLP is composed of the backend's own ops (`mlp::by_ops`).
#[cfg(feature = "wgpu")]
#[test]
fn the_composed_mlp_on_wgpu_matches_burns_layers() {
    let gpu = Device::wgpu(burn::tensor::DeviceKind::DefaultDevice).autodiff();
    check_decode_against_layers(&gpu, 1e-4);
}
