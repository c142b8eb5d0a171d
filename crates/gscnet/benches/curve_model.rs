//! Forward + backward time of the curve models on the Flex CPU backend, then of GSC-Net's
//! selective-scan kernel alone (one layer's fused softplus + scan, E = width, N = state size).
//!
//! `cargo bench -p prism-gscnet --bench curve_model -- [K] [M] [iterations]`
//! (defaults K = 10000 Gaussians, M = 8 channels, 5 iterations after one warm-up).

use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};
use prism_gscnet::cpu::scan::{ScanDims, ScanInputs, scan_backward, scan_forward};
use prism_gscnet::{CurveModelConfig, CurveModelKind, SpectralGrid};

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let k = args.first().copied().unwrap_or(10_000);
    let m = args.get(1).copied().unwrap_or(8).max(2);
    let iterations = args.get(2).copied().unwrap_or(5).max(1);
    let device = Device::flex().autodiff();
    let grid = SpectralGrid::new((0..m).map(|i| i as f32 / (m - 1) as f32).collect())
        .expect("an evenly spaced grid is valid");
    let u: Vec<f32> = (0..k).map(|i| -6.0 + 10.0 * i as f32 / k as f32).collect();
    let u = Tensor::<1>::from_data(TensorData::new(u, [k]), &device);
    let tau = grid.to_tensor(&device);
    for kind in [CurveModelKind::Gscnet, CurveModelKind::Mlp] {
        let config = CurveModelConfig {
            kind,
            ..CurveModelConfig::default()
        };
        let model = config
            .init(&grid, &device, 0)
            .expect("default config is valid");
        let step = || {
            let out = model.forward(u.clone(), tau.clone()).expect("shapes match");
            let _grads = out.powi_scalar(2).mean().backward();
        };
        step();
        let start = Instant::now();
        for _ in 0..iterations {
            step();
        }
        let ms = start.elapsed().as_secs_f64() * 1e3 / iterations as f64;
        println!(
            "{kind:?}: K = {k}, M = {m}, width {}, state {}, depth {}: forward+backward {ms:.1} ms",
            config.width, config.state_size, config.depth
        );
    }
    scan_kernel(k, m, iterations);
}

/// Times `scan_forward` and `scan_backward` on the default layer shape with inputs in the
/// trained model's ranges (raw steps z ∈ [−5, 1], A_log ∈ [0, ln 8], x, B, C ∈ [−1, 1]).
fn scan_kernel(k: usize, m: usize, iterations: usize) {
    let config = CurveModelConfig::default();
    let (e, n) = (config.width, config.state_size);
    // Deterministic pseudo-random values in [lo, hi) (fractional parts of a Weyl sequence).
    let fill = |len: usize, seed: f64, lo: f32, hi: f32| -> Vec<f32> {
        (0..len)
            .map(|i| {
                let t = (i as f64 * 0.618_033_988_749_895 + seed).fract() as f32;
                lo + (hi - lo) * t
            })
            .collect()
    };
    let x = fill(k * m * e, 0.1, -1.0, 1.0);
    let z = fill(k * m * e, 0.2, -5.0, 1.0);
    let a_log = fill(e * n, 0.3, 0.0, 8f32.ln());
    let b = fill(k * m * n, 0.4, -1.0, 1.0);
    let c = fill(k * m * n, 0.5, -1.0, 1.0);
    let d = vec![1.0f32; e];
    let gy = fill(k * m * e, 0.6, -1.0, 1.0);
    let inp = ScanInputs {
        dims: ScanDims { k, m, e, n },
        x: &x,
        delta: &z,
        a_log: &a_log,
        b: &b,
        c: &c,
        d: &d,
        softplus: true,
    };
    let time = |f: &dyn Fn()| {
        f();
        let start = Instant::now();
        for _ in 0..iterations {
            f();
        }
        start.elapsed().as_secs_f64() * 1e3 / iterations as f64
    };
    let forward = time(&|| {
        std::hint::black_box(scan_forward(&inp));
    });
    let backward = time(&|| {
        std::hint::black_box(scan_backward(&inp, &gy));
    });
    println!(
        "scan kernel: K = {k}, M = {m}, E = {e}, N = {n}: forward {forward:.1} ms, backward {backward:.1} ms"
    );
}
