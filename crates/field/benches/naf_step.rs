//! One NAF training iteration on the Flex CPU backend, split into its phases: hash-grid encode,
//! MLP (decode, sigmoid, loss), backward (the MLP's autodiff and the encoder's scatter), and the
//! optimiser (Adam over the table and the MLP). Flex runs eagerly, so each phase's time is its own.
//! It runs on the system allocator: glibc hands large freed buffers back to the kernel, so the
//! phases here also pay page faults that `prism` (jemalloc, see `crates/cli/src/main.rs`) does
//! not. Time whole runs (`prism recon configs/recon/naf.yaml`) before claiming a change's gain.
//!
//! `cargo bench -p prism-field --bench naf_step -- [points] [log2_table_size] [iterations]`
//! (defaults 98 304 points = 1024 rays × 96 samples, table 2^16 per level as configs/recon/naf.yaml,
//! 10 iterations after one warm-up).

use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor, TensorData};
use prism_field::{FieldConfig, HashGridConfig};

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let n = args.first().copied().unwrap_or(1024 * 96);
    let log2 = args.get(1).copied().unwrap_or(16) as u32;
    let iterations = args.get(2).copied().unwrap_or(10).max(1);
    let device = Device::flex().autodiff();
    let config = FieldConfig {
        hash_grid: HashGridConfig {
            log2_table_size: log2,
            ..HashGridConfig::default()
        },
        ..FieldConfig::default()
    };
    let mut field = config
        .init(0, &device)
        .expect("default field config is valid");
    let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
    // Points on a Weyl sequence in the unit cube, targets in (0, 1).
    let pts: Vec<f32> = (0..3 * n)
        .map(|i| ((i as f64 * 0.618_033_988_75).fract()) as f32)
        .collect();
    let points = Tensor::<2>::from_data(TensorData::new(pts, [n, 3]), &device);
    let target = Tensor::<1>::full([n], 0.3, &device);
    let mut total = [0f64; 4];
    for it in 0..=iterations {
        let t0 = Instant::now();
        let enc = field.encode(points.clone()).expect("shapes match");
        let t1 = Instant::now();
        let mu = sigmoid(field.decode(enc).expect("shapes match")).reshape([n]);
        let loss = (mu - target.clone()).powi_scalar(2).mean();
        let _ = loss.clone().into_scalar::<f32>();
        let t2 = Instant::now();
        let grads = loss.backward();
        let t3 = Instant::now();
        let grads = GradientsParams::from_grads(grads, &field);
        field = optim.step(1e-3, field, grads);
        let _ = field.table.val().slice([0..1, 0..1]).into_scalar::<f32>();
        let t4 = Instant::now();
        if it > 0 {
            for (k, (a, b)) in [(t0, t1), (t1, t2), (t2, t3), (t3, t4)].iter().enumerate() {
                total[k] += (*b - *a).as_secs_f64();
            }
        }
    }
    let ms = total.map(|t| t * 1e3 / iterations as f64);
    let sum: f64 = ms.iter().sum();
    println!(
        "NAF step, {n} points, {} table rows ({} parameters), {iterations} iterations:",
        config.hash_grid.layout().rows(),
        field.parameters()
    );
    for (name, t) in ["encode", "MLP + loss", "backward", "optimiser"]
        .iter()
        .zip(ms)
    {
        println!("  {name:<11} {t:8.1} ms  {:5.1} %", 100.0 * t / sum);
    }
    println!("  {:<11} {sum:8.1} ms", "total");
}
