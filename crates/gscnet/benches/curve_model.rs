//! Forward + backward time of the curve models on the Flex CPU backend.
//!
//! `cargo bench -p prism-gscnet --bench curve_model -- [K] [M] [iterations]`
//! (defaults K = 10000 Gaussians, M = 8 channels, 5 iterations after one warm-up).

use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};
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
}
