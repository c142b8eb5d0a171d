//! Benchmark of the render ops on the CPU (Flex backend, rayon), or with `BENCH_DEVICE=wgpu` (and
//! `--features wgpu`) on the wgpu backend's CubeCL kernels (the Burn-primitive reference is then
//! skipped).
//!
//! Scene: 50 000 Gaussians (`BENCH_K`) from an FDK-like initialisation of a 128³ (1 mm voxels) phantom —
//! centres sampled from the phantom's voxels with jitter, in raster order, isotropic scales from the mean distance
//! to the 3 nearest neighbours (R²-Gaussian's rule), identity rotations, density 0.15 × phantom.
//! Cone beam DSO 1000 mm, DSD 1500 mm, one view of a 256 mm detector with 256² pixels
//! (`BENCH_DETECTOR=512`: 512² pixels of 0.5 mm, the paper's detector).
//!
//! Measures (ms per iteration, median of the runs):
//! * project forward + backward of one view (loss ½‖I − I₀‖², all five gradients read back);
//! * a 32³ TV-patch voxelize + backward;
//! * the affine parallel-beam projection built from plain Burn tensor primitives (autodiff) vs the
//!   custom op on a small case, as a time ratio.
//!
//! Run: `cargo bench -p prism-render --bench render` (env `ITERS` sets the iteration count,
//! `BENCH_ONLY=affine,exact,voxelize,reference` a subset, `BENCH_DEVICE=flex|wgpu` the device,
//! `BENCH_K` the Gaussian count, `BENCH_DETECTOR` the detector's pixels per side).

use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};
use prism_render::cpu::{GaussianSlices, count_project_evaluations};
use prism_render::{
    Camera, Gaussians, ProjectOptions, Projection, VoxelGrid, VoxelizeOptions, project, voxelize,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Host {
    means: Vec<f32>,
    scales: Vec<f32>,
    rotations: Vec<f32>,
    densities: Vec<f32>,
}

/// Phantom: a water-like ellipsoid with two denser inserts (μ in mm⁻¹).
fn phantom(p: [f64; 3]) -> f64 {
    let e = |c: [f64; 3], a: [f64; 3]| {
        ((p[0] - c[0]) / a[0]).powi(2)
            + ((p[1] - c[1]) / a[1]).powi(2)
            + ((p[2] - c[2]) / a[2]).powi(2)
            <= 1.0
    };
    let mut v = 0.0;
    if e([0.0; 3], [56.0, 46.0, 58.0]) {
        v = 0.02;
        if e([18.0, 10.0, 5.0], [12.0, 9.0, 20.0]) {
            v = 0.05;
        }
        if e([-20.0, -12.0, -10.0], [8.0, 14.0, 10.0]) {
            v = 0.035;
        }
    }
    v
}

fn fdk_like_init(k: usize, seed: u64) -> Host {
    let n = 128usize;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centre = |i: usize| i as f64 + 0.5 - n as f64 / 2.0;
    let mut occupied = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [centre(x), centre(y), centre(z)];
                if phantom(p) > 0.0 {
                    occupied.push(p);
                }
            }
        }
    }
    let mut pts = Vec::with_capacity(k);
    let mut dens = Vec::with_capacity(k);
    // Raster order (z slowest), as Prism's FDK initialisation leaves its Gaussians: the GPU
    // forward kernels skip culling steps of spatially coherent runs.
    let mut picked: Vec<usize> = (0..k)
        .map(|_| rng.random_range(0..occupied.len()))
        .collect();
    picked.sort_unstable();
    for &j in &picked {
        let p = occupied[j];
        let q = [
            p[0] + rng.random_range(-0.5..0.5),
            p[1] + rng.random_range(-0.5..0.5),
            p[2] + rng.random_range(-0.5..0.5),
        ];
        pts.push(q);
        dens.push((0.15 * phantom(p) * 10.0) as f32);
    }
    // Mean distance to the 3 nearest neighbours via a 4 mm cell grid.
    let cell = 4.0;
    let nc = (n as f64 / cell).ceil() as i64 + 2;
    let idx = |p: &[f64; 3]| p.map(|v| ((v + n as f64 / 2.0) / cell).floor() as i64 + 1);
    let mut grid: Vec<Vec<usize>> = vec![Vec::new(); (nc * nc * nc) as usize];
    for (i, p) in pts.iter().enumerate() {
        let c = idx(p);
        grid[((c[2] * nc + c[1]) * nc + c[0]) as usize].push(i);
    }
    let mut scales = Vec::with_capacity(3 * k);
    for p in &pts {
        let c = idx(p);
        let mut best = [f64::INFINITY; 3];
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (x, y, z) = (c[0] + dx, c[1] + dy, c[2] + dz);
                    if x < 0 || y < 0 || z < 0 || x >= nc || y >= nc || z >= nc {
                        continue;
                    }
                    for &j in &grid[((z * nc + y) * nc + x) as usize] {
                        let q = &pts[j];
                        let d2 =
                            (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                        if d2 > 0.0 && d2 < best[2] {
                            best[2] = d2;
                            best.sort_by(|a, b| a.total_cmp(b));
                        }
                    }
                }
            }
        }
        let s = (best
            .iter()
            .filter(|v| v.is_finite())
            .map(|v| v.sqrt())
            .sum::<f64>()
            / 3.0)
            .clamp(0.3, 4.0);
        scales.extend([s as f32; 3]);
    }
    Host {
        means: pts.iter().flat_map(|p| p.map(|v| v as f32)).collect(),
        scales,
        rotations: (0..k).flat_map(|_| [1.0f32, 0.0, 0.0, 0.0]).collect(),
        densities: dens,
    }
}

fn view(theta: f64, projection: Projection, n: usize, pitch: f64) -> Camera {
    let (s, c) = theta.sin_cos();
    let (dso, dsd) = (1000.0, 1500.0);
    let (fx, fy) = match projection {
        Projection::Cone => (dsd / pitch, dsd / pitch),
        Projection::Parallel => (1.0 / pitch, 1.0 / pitch),
    };
    Camera {
        projection,
        rotation: [[-s, c, 0.0], [0.0, 0.0, -1.0], [-c, -s, 0.0]],
        translation: [0.0, 0.0, dso],
        fx,
        fy,
        cx: (n as f64 - 1.0) / 2.0,
        cy: (n as f64 - 1.0) / 2.0,
        rows: n,
        cols: n,
        sdd: dsd,
    }
}

fn tensors(h: &Host, device: &Device) -> Gaussians {
    let k = h.means.len() / 3;
    let mk = |v: &Vec<f32>, c: usize| {
        Tensor::<2>::from_data(TensorData::new(v.clone(), [k, c]), device).require_grad()
    };
    Gaussians {
        means: mk(&h.means, 3),
        scales: mk(&h.scales, 3),
        rotations: mk(&h.rotations, 4),
        densities: mk(&h.densities, 1),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Process CPU time (user + system) in ms, from `/proc/self/stat` (10 ms ticks); 0 elsewhere.
fn cpu_ms() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) * 10.0
}

/// Median wall time (ms) of `iters` runs after one warm-up, and the mean CPU time (ms) per run
/// (on a machine shared with other jobs, wall time overstates the cost; CPU time / threads is
/// the uncontended wall time of perfectly parallel work).
fn time(iters: usize, mut f: impl FnMut()) -> (f64, f64) {
    f();
    let c0 = cpu_ms();
    let wall = median(
        (0..iters)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    );
    (wall, (cpu_ms() - c0) / iters as f64)
}

/// One projection step: forward, loss, backward, read every gradient back to the host.
fn project_step(g: &Gaussians, cams: &[Camera], target: &Tensor<4>, opts: &ProjectOptions) -> f32 {
    let img = project(g, cams, None, opts).unwrap();
    let r = img - target.clone();
    let grads = (r.clone() * r).sum().mul_scalar(0.5).backward();
    let mut acc = 0.0;
    for t in [&g.means, &g.scales, &g.rotations, &g.densities] {
        acc += t.grad(&grads).unwrap().sum().into_scalar::<f32>();
    }
    acc
}

/// The affine parallel-beam projector written with plain Burn tensor ops (autodiff through
/// Burn's own graph): dense K × pixels, no tiling, no cut-off.
fn burn_reference_parallel(g: &Gaussians, cam: &Camera) -> Tensor<2> {
    let k = g.len();
    let device = g.means.device();
    let q = g.rotations.clone();
    let q = q.clone() / (q.clone() * q).sum_dim(1).sqrt();
    let c = |i: usize| q.clone().slice([0..k, i..i + 1]);
    let (w, x, y, z) = (c(0), c(1), c(2), c(3));
    let one = || Tensor::<2>::ones([k, 1], &device);
    let r = Tensor::cat(
        vec![
            one() - (y.clone() * y.clone() + z.clone() * z.clone()).mul_scalar(2.0),
            (x.clone() * y.clone() - w.clone() * z.clone()).mul_scalar(2.0),
            (x.clone() * z.clone() + w.clone() * y.clone()).mul_scalar(2.0),
            (x.clone() * y.clone() + w.clone() * z.clone()).mul_scalar(2.0),
            one() - (x.clone() * x.clone() + z.clone() * z.clone()).mul_scalar(2.0),
            (y.clone() * z.clone() - w.clone() * x.clone()).mul_scalar(2.0),
            (x.clone() * z.clone() - w.clone() * y.clone()).mul_scalar(2.0),
            (y.clone() * z.clone() + w.clone() * x.clone()).mul_scalar(2.0),
            one() - (x.clone() * x + y.clone() * y).mul_scalar(2.0),
        ],
        1,
    )
    .reshape([k, 3, 3]);
    let wm = Tensor::<2>::from_data(
        TensorData::new(
            cam.rotation
                .iter()
                .flatten()
                .map(|&v| v as f32)
                .collect::<Vec<_>>(),
            [3, 3],
        ),
        &device,
    );
    let wr = wm.clone().reshape([1, 3, 3]).expand([k, 3, 3]).matmul(r); // camera-frame axes [K,3,3]
    let s2 = g.scales.clone() * g.scales.clone();
    let cov = (wr.clone() * s2.clone().reshape([k, 1, 3])).matmul(wr.clone().swap_dims(1, 2));
    // (W Σ⁻¹ Wᵀ)_zz = Σ_j (W R)_zj² / s_j².
    let wrz = wr.slice([0..k, 2..3, 0..3]).reshape([k, 3]);
    let kappa = ((wrz.clone() * wrz) / s2).sum_dim(1);
    let mu = kappa.recip().mul_scalar(2.0 * std::f32::consts::PI).sqrt();
    let (fx, fy) = (cam.fx as f32, cam.fy as f32);
    let e = |i: usize, j: usize| {
        cov.clone()
            .slice([0..k, i..i + 1, j..j + 1])
            .reshape([k, 1])
    };
    let (a, b, cc) = (
        e(0, 0).mul_scalar(fx * fx),
        e(0, 1).mul_scalar(fx * fy),
        e(1, 1).mul_scalar(fy * fy),
    );
    let det = a.clone() * cc.clone() - b.clone() * b.clone();
    let (ca, cb, ccc) = (cc / det.clone(), b.neg() / det.clone(), a / det);
    let t = g.means.clone().matmul(wm.transpose())
        + Tensor::<2>::from_data(
            TensorData::new(cam.translation.map(|v| v as f32).to_vec(), [1, 3]),
            &device,
        );
    let mx = t
        .clone()
        .slice([0..k, 0..1])
        .mul_scalar(fx)
        .add_scalar(cam.cx as f32);
    let my = t
        .slice([0..k, 1..2])
        .mul_scalar(fy)
        .add_scalar(cam.cy as f32);
    let n = cam.rows * cam.cols;
    let px: Vec<f32> = (0..n).map(|i| (i % cam.cols) as f32).collect();
    let py: Vec<f32> = (0..n).map(|i| (i / cam.cols) as f32).collect();
    let px = Tensor::<2>::from_data(TensorData::new(px, [1, n]), &device);
    let py = Tensor::<2>::from_data(TensorData::new(py, [1, n]), &device);
    let dx = px - mx;
    let dy = py - my;
    let power = (ca * dx.clone() * dx.clone()
        + cb.mul_scalar(2.0) * dx * dy.clone()
        + ccc * dy.clone() * dy)
        .mul_scalar(-0.5);
    ((g.densities.clone() * mu) * power.exp()).sum_dim(0)
}

fn enabled(section: &str) -> bool {
    std::env::var("BENCH_ONLY").map_or(true, |v| v.split(',').any(|s| s.trim() == section))
}

/// The autodiff device named by `BENCH_DEVICE` (default Flex).
fn bench_device() -> Device {
    match std::env::var("BENCH_DEVICE").as_deref() {
        Err(_) | Ok("flex") => Device::flex().autodiff(),
        #[cfg(feature = "wgpu")]
        Ok("wgpu") => Device::wgpu(burn::tensor::DeviceKind::DefaultDevice).autodiff(),
        Ok(other) => panic!("BENCH_DEVICE={other}: expected flex, or wgpu with --features wgpu"),
    }
}

/// A positive integer from the environment, or `default`.
fn env_usize(name: &str, default: usize) -> usize {
    match std::env::var(name) {
        Ok(v) => match v.parse() {
            Ok(n) if n > 0 => n,
            _ => panic!("{name}={v}: expected a positive integer"),
        },
        Err(_) => default,
    }
}

fn main() {
    let iters = env_usize("ITERS", 10);
    let det = env_usize("BENCH_DETECTOR", 256);
    let ad = bench_device();
    let gpu = prism_render::is_gpu(&ad);
    println!(
        "device: {}; threads: {}",
        if gpu { "wgpu" } else { "flex" },
        rayon::current_num_threads()
    );

    let t0 = Instant::now();
    let host = fdk_like_init(env_usize("BENCH_K", 50_000), 42);
    let k = host.means.len() / 3;
    let mean_scale = host.scales.iter().map(|&v| v as f64).sum::<f64>() / host.scales.len() as f64;
    println!(
        "scene: {k} Gaussians, mean σ {mean_scale:.2} mm (init {:.1} s)",
        t0.elapsed().as_secs_f64()
    );
    let g = tensors(&host, &ad);
    let slices = GaussianSlices {
        means: &host.means,
        scales: &host.scales,
        rotations: &host.rotations,
        densities: &host.densities,
        channels: 1,
    };

    for (name, opts) in [
        ("affine", ProjectOptions::default()),
        ("exact", ProjectOptions::exact()),
    ] {
        if !enabled(name) {
            continue;
        }
        let cams = [view(0.4, Projection::Cone, det, 256.0 / det as f64)];
        let target = project(&g, &cams, None, &opts)
            .unwrap()
            .detach()
            .mul_scalar(0.9);
        let evals = count_project_evaluations(&slices, &cams, &opts);
        let (fwd, fwd_cpu) = time(iters, || {
            let _ = project(&g, &cams, None, &opts)
                .unwrap()
                .sum()
                .into_scalar::<f32>();
        });
        let (step, step_cpu) = time(iters, || {
            let _ = project_step(&g, &cams, &target, &opts);
        });
        println!(
            "project {name} cone {det}², K = {k}: forward {fwd:.1} ms (CPU {fwd_cpu:.0} ms), \
             forward+backward {step:.1} ms/iter (CPU {step_cpu:.0} ms); {evals} Gaussian–pixel \
             evaluations per pass → {:.0} M/s forward, {:.0} M/s forward+backward (2 passes)",
            evals as f64 / fwd / 1e3,
            2.0 * evals as f64 / step / 1e3
        );
    }
    if enabled("voxelize") {
        bench_voxelize(&g, iters);
    }
    if enabled("reference") && !gpu {
        bench_reference(&host, &ad, iters);
    }
}

fn bench_voxelize(g: &Gaussians, iters: usize) {
    let k = g.len();
    // 32³ TV patch (1 mm voxels) at a random place inside the volume, voxelize + backward.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let patches: Vec<VoxelGrid> = (0..iters + 1)
        .map(|_| VoxelGrid {
            dims: [32, 32, 32],
            voxel: [1.0; 3],
            offset: [0, 1, 2].map(|_| rng.random_range(-40.0..40.0)),
        })
        .collect();
    let mut i = 0;
    let (tv, tv_cpu) = time(iters, || {
        let grid = patches[i % patches.len()];
        i += 1;
        let vol = voxelize(g, &grid, &VoxelizeOptions::default()).unwrap();
        let grads = vol.sum().backward();
        let mut acc = 0.0;
        for t in [&g.means, &g.scales, &g.rotations, &g.densities] {
            acc += t.grad(&grads).unwrap().sum().into_scalar::<f32>();
        }
        std::hint::black_box(acc);
    });
    println!("voxelize 32³ TV patch + backward, K = {k}: {tv:.1} ms/iter (CPU {tv_cpu:.0} ms)");
    let full = VoxelGrid {
        dims: [128, 128, 128],
        voxel: [1.0; 3],
        offset: [0.0; 3],
    };
    let (vf, vf_cpu) = time(iters.min(3), || {
        let _ = voxelize(g, &full, &VoxelizeOptions::default())
            .unwrap()
            .detach()
            .sum()
            .into_scalar::<f32>();
    });
    println!("voxelize full 128³ forward, K = {k}: {vf:.1} ms (CPU {vf_cpu:.0} ms)");
}

fn bench_reference(host: &Host, ad: &Device, iters: usize) {
    // Custom op vs the same projector from Burn primitives (small: K = 256, 32² parallel view).
    let small = Host {
        means: host.means[..3 * 256].to_vec(),
        scales: host.scales[..3 * 256].iter().map(|v| v * 4.0).collect(),
        rotations: host.rotations[..4 * 256].to_vec(),
        densities: host.densities[..256].to_vec(),
    };
    let gs = tensors(&small, ad);
    let cam = view(0.4, Projection::Parallel, 32, 4.5);
    let wide = ProjectOptions {
        cutoff: 1e3,
        ..Default::default()
    };
    let ours = project(&gs, &[cam], None, &wide)
        .unwrap()
        .reshape([1, 32 * 32]);
    let theirs = burn_reference_parallel(&gs, &cam);
    let diff = (ours - theirs.clone()).abs().max().into_scalar::<f32>();
    let peak = theirs.max().into_scalar::<f32>();
    println!(
        "burn-primitive reference vs custom op (no cut-off): max diff / peak = {:.1e}",
        diff / peak
    );
    let read = |grads: &burn::tensor::Gradients| {
        let mut acc = 0.0;
        for t in [&gs.means, &gs.scales, &gs.rotations, &gs.densities] {
            acc += t.grad(grads).unwrap().sum().into_scalar::<f32>();
        }
        acc
    };
    let (custom, _) = time(iters, || {
        let grads = project(&gs, &[cam], None, &ProjectOptions::default())
            .unwrap()
            .sum()
            .backward();
        std::hint::black_box(read(&grads));
    });
    let (reference, _) = time(iters, || {
        let grads = burn_reference_parallel(&gs, &cam).sum().backward();
        std::hint::black_box(read(&grads));
    });
    println!(
        "small case (K = 256, 32² parallel) forward+backward: custom op {custom:.2} ms, Burn primitives {reference:.2} ms \
         → ratio {:.1}×",
        reference / custom
    );
}
