//! Parity of the CubeCL kernels with the CPU kernels ([`crate::cpu`], the reference validated
//! against analytic integrals and finite differences): the same inputs through both, forward
//! within 1e-5 and gradients within 1e-4 of each output's largest magnitude. Runs on any wgpu
//! adapter; without a GPU, Mesa's lavapipe (`apt-get install mesa-vulkan-drivers`).
//!
//! The tolerances follow from f32: the CPU prepares each Gaussian in f64 and rounds once, the
//! GPU works in f32 throughout (relative rounding ~1e-7 per operation, amplified by the
//! conditioning of the 2D covariance for the forward and by pixel sums of mixed-sign upstream
//! gradients for the backward).

use burn::backend::ops::FloatTensorOps;
use burn::tensor::{Device, DeviceKind, Tensor, TensorData};
use burn_cubecl::{CubeBackend, cubecl};

use super::STEP;

use crate::camera::Camera;
use crate::cpu::tests::{Params, cone, parallel};
use crate::cpu::{project_backward, project_forward, voxelize_backward, voxelize_forward};
use crate::ops::tests::{tensors as tracked, to_vec, weights};
use crate::ops::{Gaussians, project, voxelize};

/// Gaussians on `device` that require grad.
fn tensors(p: &Params, device: &Device) -> Gaussians {
    tracked(p, device, true)
}
use crate::options::{ProjectOptions, ProjectionMode, VoxelGrid, VoxelizeOptions};

fn gpu() -> Device {
    Device::wgpu(DeviceKind::DefaultDevice)
}

/// `max |gpu − cpu| / max(max |cpu|, floor)` (0 when both are all zero), asserted `≤ tol`.
fn check(what: &str, gpu: &[f32], cpu: &[f32], tol: f64) -> f64 {
    check_with_floor(what, gpu, cpu, tol, 0.0)
}

/// The quaternion gradient's natural scale: a rotation by δ changes the covariance as much as
/// relative scale changes of δ do, so `|∂L/∂q| ~ max_j |s_j ∂L/∂s_j|`. It is the reference where
/// the rotation gradient vanishes by symmetry (an isotropic Gaussian).
fn rotation_floor(p: &Params, grad_scales: &[f32]) -> f64 {
    p.scales
        .iter()
        .zip(grad_scales)
        .fold(0.0f64, |m, (&s, &g)| m.max((s as f64 * g as f64).abs()))
}

fn check_with_floor(what: &str, gpu: &[f32], cpu: &[f32], tol: f64, floor: f64) -> f64 {
    assert_eq!(gpu.len(), cpu.len(), "{what}: length");
    let scale = cpu
        .iter()
        .fold(0.0f64, |m, &v| m.max((v as f64).abs()))
        .max(floor);
    let err = gpu
        .iter()
        .zip(cpu)
        .fold(0.0f64, |m, (&a, &b)| m.max((a as f64 - b as f64).abs()));
    let rel = if scale > 0.0 { err / scale } else { err };
    println!("parity {what}: max |Δ| / max |cpu| = {rel:.3e}");
    assert!(
        gpu.iter().all(|v| v.is_finite()),
        "{what}: non-finite GPU value"
    );
    assert!(rel <= tol, "{what}: {rel:e} > {tol:e}");
    rel
}

const FORWARD_TOL: f64 = 1e-5;
const GRAD_TOL: f64 = 1e-4;
/// Voxelization of a needle or sheet thinner than 1/400 of a voxel against the f64 truth. Any f32
/// evaluation is off by about `ε_op · |d| / s_min · max(e·G)`, `ε_op` the relative error of the
/// operations forming the scaled axes `w_j = r_j / s_j` (quaternion normalisation, division):
/// IEEE rounding (the CPU kernel) gives `6e-8 · 55 / 0.01 · 0.61 = 2e-4` (measured 2.8e-5), but
/// Vulkan only requires 2.5 ULP for a division and 2 ULP for `inversesqrt`, so on a GPU
/// `ε_op ≈ 2.5 · 1.2e-7 = 3e-7` and the bound is 1.0e-3 (measured on an NVIDIA H200, driver
/// 580.159: value 3.2e-4, gradients 2.5e-4 to 3.2e-4; on lavapipe 1.5e-5 and 1.2e-5 to 1.5e-5).
const THIN_VOXEL_TOL: f64 = 1e-3;

/// Projection forward and backward (with the screen-offset gradient) on the GPU against the
/// CPU kernels, at zero screen offsets (the trainer's probe).
fn project_parity(name: &str, p: &Params, cams: &[Camera], opts: &ProjectOptions) {
    let k = p.means.len() / 3;
    project_parity_with(name, p, cams, opts, &vec![0.0; cams.len() * k * 2]);
}

/// [`project_parity`] with the given `[V, K, 2]` screen offsets (pixels).
fn project_parity_with(
    name: &str,
    p: &Params,
    cams: &[Camera],
    opts: &ProjectOptions,
    screen: &[f32],
) {
    let opts = *opts;
    let name = &format!("{name} {:?}", opts.mode);
    let k = p.means.len() / 3;
    let v = cams.len();
    let (rows, cols) = (cams[0].rows, cams[0].cols);
    let device = gpu().autodiff();
    let g = tensors(p, &device);
    let probe =
        Tensor::<3>::from_data(TensorData::new(screen.to_vec(), [v, k, 2]), &device).require_grad();
    let img = project(&g, cams, Some(&probe), &opts).expect("project");
    let want = project_forward(&p.slices(), screen, cams, &opts);
    check(
        &format!("{name} forward"),
        &to_vec(img.clone()),
        &want,
        FORWARD_TOL,
    );
    let r = weights(v * p.channels * rows * cols, 7);
    let rt = Tensor::<4>::from_data(
        TensorData::new(r.clone(), [v, p.channels, rows, cols]),
        &device,
    );
    let grads = (img * rt).sum().backward();
    let want = project_backward(&p.slices(), screen, cams, &opts, &r);
    let floor = rotation_floor(p, &want.scales);
    let tol = match opts.mode {
        ProjectionMode::Affine => affine_grad_tol(p),
        ProjectionMode::Exact => exact_grad_tol(p, opts.cutoff),
    };
    for (what, t, w) in [
        ("means", &g.means, &want.means),
        ("scales", &g.scales, &want.scales),
        ("rotations", &g.rotations, &want.rotations),
        ("densities", &g.densities, &want.densities),
    ] {
        let got = to_vec(t.grad(&grads).expect("gradient"));
        let floor = match what {
            "rotations" => floor,
            "means" | "scales" => position_floor(p, &want.densities),
            _ => 0.0,
        };
        check_with_floor(&format!("{name} ∂{what}"), &got, w, tol, floor);
    }
    let got = to_vec(probe.grad(&grads).expect("screen gradient"));
    check(&format!("{name} ∂screen"), &got, &want.screen, tol);
}

/// The natural scale of the mean and scale gradients: moving a Gaussian by one standard
/// deviation, or changing its scale by that much, changes its contribution by about its whole
/// value, so `|∂L/∂mean|, |∂L/∂s| ~ |ρ ∂L/∂ρ| / s`. It is the reference where these gradients
/// nearly cancel: a Gaussian much larger than the scene (the "huge scale" case) is flat over
/// every ray segment, and the exact mode's mean and scale gradients there are 10⁻⁷–10⁻⁸ of that
/// scale (differences of the two segment-end terms), far below what f32 resolves.
fn position_floor(p: &Params, grad_densities: &[f32]) -> f64 {
    let m = p.channels;
    (0..p.scales.len() / 3).fold(0.0f64, |acc, i| {
        let s_max = p.scales[3 * i..3 * i + 3]
            .iter()
            .fold(0.0f64, |a, &v| a.max(v as f64));
        let w: f64 = (0..m)
            .map(|c| (p.densities[m * i + c] as f64 * grad_densities[m * i + c] as f64).abs())
            .sum();
        acc.max(w / s_max)
    })
}

/// Gradient tolerance of the exact mode. A ray that crosses a needle or sheet far from its
/// centre (up to `cutoff · s_max` away) has its thin-axis coordinate `ã_thin · w` formed in f32
/// from an offset of that size, an absolute error of about `ε · cutoff · s_max / s_min`
/// standard deviations, which enters the gradients at first order (the value only at second
/// order, through `q`). The CPU evaluates in f64. That bound (1.2e-7 · 3 · 10⁴ = 3.6e-3 for the
/// 10⁴:1 needle and sheets; the measured error is 1.4e-3) or [`GRAD_TOL`], whichever is larger.
fn exact_grad_tol(p: &Params, cutoff: f64) -> f64 {
    GRAD_TOL.max(f32::EPSILON as f64 * cutoff * aspect(p))
}

/// Gradient tolerance of the affine mode. The rotation gradient of a Gaussian with scales
/// `s_min ≪ s_max` is a difference of covariance terms of size `s_max²` that must resolve the
/// thin axis's `s_min·s_max` (`∂(R S² Rᵀ)/∂q` mixes the axes); the GPU forms them in f32, so its
/// relative error relative to the gradient's scale is about `ε · s_max / s_min`
/// (1.2e-7 · 10⁴ = 1.2e-3 for the 10⁴:1 needle; measured 1.003e-4 on an NVIDIA H200, below 1e-4
/// on lavapipe). That bound or [`GRAD_TOL`], whichever is larger.
fn affine_grad_tol(p: &Params) -> f64 {
    GRAD_TOL.max(f32::EPSILON as f64 * aspect(p))
}

/// The largest `s_max / s_min` over the Gaussians.
fn aspect(p: &Params) -> f64 {
    p.scales.chunks(3).fold(1.0f64, |m, s| {
        let (lo, hi) = s.iter().fold((f64::MAX, 0.0f64), |(lo, hi), &v| {
            (lo.min(v as f64), hi.max(v as f64))
        });
        m.max(hi / lo)
    })
}

/// f64 truth of a voxelization's gradients for upstream gradient `r`: every Gaussian at every
/// voxel centre, chained by [`crate::gaussian_math::voxel_backward`].
fn reference_voxelize_backward_f64(
    p: &Params,
    grid: &VoxelGrid,
    cutoff: f64,
    r: &[f32],
) -> [Vec<f32>; 4] {
    use crate::gaussian_math::{GaussianGeom, dot, mat_vec, shape3, voxel_backward};
    let k = p.means.len() / 3;
    let m = p.channels;
    let [nx, ny, nz] = grid.dims;
    let mut out: [Vec<f32>; 4] = [
        vec![0.0; 3 * k],
        vec![0.0; 3 * k],
        vec![0.0; 4 * k],
        vec![0.0; m * k],
    ];
    for i in 0..k {
        let f = |v: &[f32], n: usize| -> Vec<f64> {
            v[n * i..n * i + n].iter().map(|&x| x as f64).collect()
        };
        let (mean, scale, quat) = (f(&p.means, 3), f(&p.scales, 3), f(&p.rotations, 4));
        let geom = GaussianGeom {
            mean: [mean[0], mean[1], mean[2]],
            scale: [scale[0], scale[1], scale[2]],
            quat: [quat[0], quat[1], quat[2], quat[3]],
        };
        let Some(sh) = shape3(&geom) else { continue };
        let mut sums = vec![0.0f64; m];
        let mut sum_d = [0.0f64; 3];
        let mut sum_dd = [[0.0f64; 3]; 3];
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let c = [grid.centre(0, x), grid.centre(1, y), grid.centre(2, z)];
                    let d = [c[0] - mean[0], c[1] - mean[1], c[2] - mean[2]];
                    let q = dot(d, mat_vec(&sh.prec, d));
                    if q > cutoff * cutoff {
                        continue;
                    }
                    let g = (-0.5 * q).exp();
                    let vox = (z * ny + y) * nx + x;
                    let mut w = 0.0;
                    for ch in 0..m {
                        let gc = r[ch * grid.len() + vox] as f64;
                        sums[ch] += gc * g;
                        w += p.densities[m * i + ch] as f64 * gc * g;
                    }
                    for a in 0..3 {
                        sum_d[a] += w * d[a];
                        for b in 0..3 {
                            sum_dd[a][b] += w * d[a] * d[b];
                        }
                    }
                }
            }
        }
        let geo = voxel_backward(&geom, sum_d, &sum_dd);
        for a in 0..3 {
            out[0][3 * i + a] = geo.mean[a] as f32;
            out[1][3 * i + a] = geo.scale[a] as f32;
        }
        for a in 0..4 {
            out[2][4 * i + a] = geo.quat[a] as f32;
        }
        for ch in 0..m {
            out[3][m * i + ch] = sums[ch] as f32;
        }
    }
    out
}

/// `max |a − b| / max |b|`.
fn rel(a: &[f32], b: &[f32]) -> f64 {
    let s = b.iter().fold(0.0f64, |m, &v| m.max((v as f64).abs()));
    let e = a
        .iter()
        .zip(b)
        .fold(0.0f64, |m, (&x, &y)| m.max((x as f64 - y as f64).abs()));
    if s > 0.0 { e / s } else { e }
}

fn voxel_parity(name: &str, p: &Params, grid: &VoxelGrid, thin: bool) {
    let opts = VoxelizeOptions::default();
    let device = gpu().autodiff();
    let g = tensors(p, &device);
    let vol = voxelize(&g, grid, &opts).expect("voxelize");
    let want = voxelize_forward(&p.slices(), grid, &opts);
    let k = p.means.len() / 3;
    let truth: Vec<f32> =
        crate::cpu::tests::reference_voxelize_f64(&p.flat(), k, p.channels, grid, opts.cutoff)
            .iter()
            .map(|&v| v as f32)
            .collect();
    let got = to_vec(vol.clone());
    let [nx, ny, nz] = grid.dims;
    let r = weights(p.channels * nx * ny * nz, 11);
    let rt = Tensor::<4>::from_data(
        TensorData::new(r.clone(), [p.channels, nz, ny, nx]),
        &device,
    );
    let grads = (vol * rt).sum().backward();
    let cpu = voxelize_backward(&p.slices(), grid, &opts, &r);
    let truth_grads = reference_voxelize_backward_f64(p, grid, opts.cutoff, &r);
    let cpu_grads = [&cpu.means, &cpu.scales, &cpu.rotations, &cpu.densities];
    let gpu_grads: Vec<Vec<f32>> = [&g.means, &g.scales, &g.rotations, &g.densities]
        .iter()
        .map(|t| to_vec(t.grad(&grads).expect("gradient")))
        .collect();
    println!(
        "{name} voxelize vs f64 truth: value cpu {:.3e} gpu {:.3e}; ∂(means, scales, rotations, densities) cpu {:.1e} {:.1e} {:.1e} {:.1e} gpu {:.1e} {:.1e} {:.1e} {:.1e}",
        rel(&want, &truth),
        rel(&got, &truth),
        rel(cpu_grads[0], &truth_grads[0]),
        rel(cpu_grads[1], &truth_grads[1]),
        rel(cpu_grads[2], &truth_grads[2]),
        rel(cpu_grads[3], &truth_grads[3]),
        rel(&gpu_grads[0], &truth_grads[0]),
        rel(&gpu_grads[1], &truth_grads[1]),
        rel(&gpu_grads[2], &truth_grads[2]),
        rel(&gpu_grads[3], &truth_grads[3]),
    );
    if thin {
        // A needle or sheet thinner than 1/400 of a voxel: the CPU kernel's f32 is off the f64
        // truth too (see the printout), so the GPU is held to the truth (THIN_VOXEL_TOL).
        check(
            &format!("{name} voxelize vs f64 truth"),
            &got,
            &truth,
            THIN_VOXEL_TOL,
        );
        let floor = rotation_floor(p, &truth_grads[1]);
        for (i, what) in ["means", "scales", "rotations", "densities"]
            .iter()
            .enumerate()
        {
            check_with_floor(
                &format!("{name} voxelize ∂{what} vs f64 truth"),
                &gpu_grads[i],
                &truth_grads[i],
                THIN_VOXEL_TOL,
                if i == 2 { floor } else { 0.0 },
            );
        }
        return;
    }
    check(&format!("{name} voxelize"), &got, &want, FORWARD_TOL);
    let floor = rotation_floor(p, cpu_grads[1]);
    for (i, what) in ["means", "scales", "rotations", "densities"]
        .iter()
        .enumerate()
    {
        let floor = if i == 2 { floor } else { 0.0 };
        check_with_floor(
            &format!("{name} voxelize ∂{what}"),
            &gpu_grads[i],
            cpu_grads[i],
            GRAD_TOL,
            floor,
        );
    }
}

#[test]
fn projection_matches_cpu_cone_and_parallel() {
    // 300 Gaussians (more than one culling chunk), 2 channels, 2 views, 40×36 detector (partial
    // edge tiles); affine and exact mode.
    let p = Params::random(300, 2, 20.0, (0.8, 4.0), 5);
    let cone_views = [cone(0.2, 40, 36, 1.5), cone(1.9, 40, 36, 1.5)];
    let par_views = [parallel(0.4, 40, 36, 1.5), parallel(2.5, 40, 36, 1.5)];
    let p1 = Params::random(100, 1, 20.0, (0.8, 4.0), 6);
    let p8 = Params::random(100, 8, 20.0, (0.8, 4.0), 7);
    for opts in [ProjectOptions::default(), ProjectOptions::exact()] {
        project_parity("cone", &p, &cone_views, &opts);
        project_parity("parallel", &p, &par_views, &opts);
        // One channel (the structural projection of stage 1) and many channels (8).
        project_parity("cone M=1", &p1, &cone_views[..1], &opts);
        project_parity("cone M=8", &p8, &cone_views[..1], &opts);
        // Non-zero screen offsets (within ±1 px): they shift the centres, and the cone-beam gradient
        // picks up their depth dependence.
        let offsets = weights(2 * 2 * 300, 13)
            .iter()
            .map(|w| 2.0 * w)
            .collect::<Vec<_>>();
        project_parity_with("cone offsets", &p, &cone_views, &opts, &offsets);
        project_parity_with("parallel offsets", &p, &par_views, &opts, &offsets);
    }
}

/// `p` with its Gaussians in order of increasing `z`, as raster-ordered initialisation leaves
/// them: consecutive culling steps cover bands of detector rows and of grid slices, so the
/// forward kernels skip steps (the outputs must not change).
fn sorted_by_z(p: &Params) -> Params {
    let k = p.means.len() / 3;
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| p.means[3 * a + 2].total_cmp(&p.means[3 * b + 2]));
    p.select(&order)
}

#[test]
fn step_skipping_keeps_the_outputs() {
    // 3000 Gaussians sorted by z (3 culling steps, each a band of rows / slices), small enough
    // that many tiles and bricks miss a step's union box.
    let p = sorted_by_z(&Params::random(3000, 2, 20.0, (0.5, 1.5), 12));
    let views = [cone(0.7, 40, 36, 1.5)];
    for opts in [ProjectOptions::default(), ProjectOptions::exact()] {
        project_parity("sorted", &p, &views, &opts);
    }
    let grid = VoxelGrid {
        dims: [24, 20, 24],
        voxel: [2.0; 3],
        offset: [0.0; 3],
    };
    voxel_parity("sorted", &p, &grid, false);
}

#[test]
fn step_bounds_are_the_union_of_live_boxes() {
    // 2500 affine records with the box [x0, x1, y0, y1]; every third is culled (an empty box),
    // and the last step holds only culled records.
    let (k, sets) = (2500usize, 2usize);
    let (width, bx) = (super::project::AFFINE_WIDTH, super::project::AFFINE_BOX);
    let mut rec = vec![0.0f32; sets * k * width];
    for set in 0..sets {
        for j in 0..k {
            let o = (set * k + j) * width + bx;
            let live = j % 3 != 0 && j < 2 * STEP;
            let x0 = ((j * 7 + set * 3) % 50) as f32;
            let y0 = ((j * 13) % 40) as f32;
            let (w, h) = if live { (3.0, 2.0) } else { (0.0, 0.0) };
            rec[o..o + 4].copy_from_slice(&[x0, x0 + w, y0, y0 + h]);
        }
    }
    let dev = gpu().inner();
    let burn::backend::DispatchDevice::Cube(device) = dev.as_dispatch() else {
        panic!("the wgpu device is a CubeCL device");
    };
    let records = CubeBackend::float_from_data(TensorData::new(rec.clone(), [rec.len()]), device);
    let bounds = super::culling::step_bounds(&records, k, sets, super::culling::AFFINE_BOXES);
    let got = cubecl::future::reader::read_sync(CubeBackend::float_into_data(bounds))
        .expect("read back")
        .try_into_vec::<f32>()
        .expect("f32");
    let steps = k.div_ceil(STEP);
    assert_eq!(got.len(), sets * steps * 4);
    for set in 0..sets {
        for step in 0..steps {
            let e = super::culling::EMPTY_LO;
            let mut want = [e, -e, e, -e];
            for j in step * STEP..((step + 1) * STEP).min(k) {
                let o = (set * k + j) * width + bx;
                if rec[o] < rec[o + 1] && rec[o + 2] < rec[o + 3] {
                    want = [
                        want[0].min(rec[o]),
                        want[1].max(rec[o + 1]),
                        want[2].min(rec[o + 2]),
                        want[3].max(rec[o + 3]),
                    ];
                }
            }
            let o = (set * steps + step) * 4;
            assert_eq!(&got[o..o + 4], &want, "set {set} step {step}");
        }
    }
}

#[test]
fn voxelize_matches_cpu() {
    let p = Params::random(300, 2, 20.0, (0.8, 4.0), 8);
    let grid = VoxelGrid {
        dims: [20, 17, 13],
        voxel: [2.0, 2.2, 2.5],
        offset: [1.0, -0.5, 0.3],
    };
    voxel_parity("grid", &p, &grid, false);
    let p1 = Params::random(100, 1, 20.0, (0.8, 4.0), 9);
    voxel_parity("grid M=1", &p1, &grid, false);
}

/// One Gaussian with the given mean, scale, quaternion and density.
fn one(mean: [f32; 3], scale: [f32; 3], quat: [f32; 4], density: f32) -> Params {
    Params {
        means: mean.to_vec(),
        scales: scale.to_vec(),
        rotations: quat.to_vec(),
        densities: vec![density],
        channels: 1,
    }
}

/// The stiff cases of the render issue (needles, sheets, tiny and huge scales and densities),
/// each with a moderate companion Gaussian so every output has a non-trivial scale.
#[test]
fn stiff_cases_match_cpu() {
    let cams = [cone(0.3, 32, 32, 3.0)];
    let end_on = [cone(0.0, 32, 32, 3.0)];
    let q = [0.9, 0.2, -0.3, 0.25];
    let id = [1.0, 0.0, 0.0, 0.0];
    let cases: Vec<(&str, Params, &[Camera])> = vec![
        (
            "needle",
            one([2.0, -3.0, 1.0], [0.01, 100.0, 1.0], q, 1.0),
            &cams,
        ),
        (
            "sheet",
            one([2.0, -3.0, 1.0], [100.0, 100.0, 0.01], q, 1.0),
            &cams,
        ),
        (
            "thin sheet",
            one([2.0, -3.0, 1.0], [0.001, 10.0, 10.0], q, 1.0),
            &cams,
        ),
        (
            "needle end-on",
            one([0.0; 3], [100.0, 0.01, 0.01], id, 1.0),
            &end_on,
        ),
        (
            "sheet edge-on",
            one([0.0; 3], [100.0, 100.0, 0.01], id, 1.0),
            &end_on,
        ),
        (
            "tiny scale",
            one([1.0, 1.0, 1.0], [6.4e-6; 3], id, 1.0),
            &cams,
        ),
        ("huge scale", one([0.0; 3], [6400.0; 3], id, 1.0), &cams),
        (
            "tiny density",
            one([1.0, 2.0, 0.0], [3.0, 2.0, 4.0], id, 1e-8),
            &cams,
        ),
        (
            "huge density",
            one([1.0, 2.0, 0.0], [3.0, 2.0, 4.0], id, 1e6),
            &cams,
        ),
    ];
    let grid = VoxelGrid {
        dims: [16, 16, 16],
        voxel: [4.0; 3],
        offset: [0.0; 3],
    };
    for (name, p, views) in cases {
        for opts in [ProjectOptions::default(), ProjectOptions::exact()] {
            project_parity(name, &p, views, &opts);
        }
        let par: Vec<Camera> = views
            .iter()
            .map(|c| Camera {
                projection: crate::Projection::Parallel,
                fx: 0.5,
                fy: 0.5,
                ..*c
            })
            .collect();
        for opts in [ProjectOptions::default(), ProjectOptions::exact()] {
            project_parity(&format!("{name} parallel"), &p, &par, &opts);
        }
        let thin = p.scales.iter().any(|&s| s < 0.1) && p.scales.iter().any(|&s| s > 1.0);
        voxel_parity(name, &p, &grid, thin);
    }
}

#[test]
fn empty_inputs_give_zeros() {
    let p = Params::random(0, 2, 5.0, (1.0, 2.0), 1);
    let g = tensors(&p, &gpu().autodiff());
    let img = project(
        &g,
        &[cone(0.0, 8, 8, 1.0)],
        None,
        &ProjectOptions::default(),
    )
    .unwrap();
    assert!(to_vec(img).iter().all(|&v| v == 0.0));
}
