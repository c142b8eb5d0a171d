//! Tile kernels against untiled f64 references, closed forms and central differences.

use super::*;
use crate::camera::{Camera, Projection};
use crate::gaussian_math::{self as gm, GaussianGeom, SQRT_2PI};
use crate::options::{ProjectOptions, ProjectionMode, VoxelGrid, VoxelizeOptions};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Owned Gaussian parameters for tests.
#[derive(Clone, Debug)]
pub(crate) struct Params {
    pub means: Vec<f32>,
    pub scales: Vec<f32>,
    pub rotations: Vec<f32>,
    pub densities: Vec<f32>,
    pub channels: usize,
}

impl Params {
    pub fn slices(&self) -> GaussianSlices<'_> {
        GaussianSlices {
            means: &self.means,
            scales: &self.scales,
            rotations: &self.rotations,
            densities: &self.densities,
            channels: self.channels,
        }
    }

    pub fn random(k: usize, channels: usize, extent: f32, sigma: (f32, f32), seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut p = Params {
            means: vec![],
            scales: vec![],
            rotations: vec![],
            densities: vec![],
            channels,
        };
        for _ in 0..k {
            for _ in 0..3 {
                p.means.push(rng.random_range(-extent..extent));
                p.scales.push(rng.random_range(sigma.0..sigma.1));
            }
            for _ in 0..4 {
                p.rotations.push(rng.random_range(-1.0..1.0));
            }
            for _ in 0..channels {
                p.densities.push(rng.random_range(0.2..1.5));
            }
        }
        p
    }

    /// The Gaussians `order` names, in that order.
    pub(crate) fn select(&self, order: &[usize]) -> Self {
        let pick = |v: &[f32], w: usize| -> Vec<f32> {
            order
                .iter()
                .flat_map(|&i| &v[w * i..w * (i + 1)])
                .copied()
                .collect()
        };
        Params {
            means: pick(&self.means, 3),
            scales: pick(&self.scales, 3),
            rotations: pick(&self.rotations, 4),
            densities: pick(&self.densities, self.channels),
            channels: self.channels,
        }
    }

    /// All parameters as one f64 vector (means, scales, rotations, densities).
    pub(crate) fn flat(&self) -> Vec<f64> {
        self.means
            .iter()
            .chain(&self.scales)
            .chain(&self.rotations)
            .chain(&self.densities)
            .map(|&v| v as f64)
            .collect()
    }
}

/// A cone view at angle θ with the Prism convention (source at DSO·(cos θ, sin θ, 0)).
pub(crate) fn cone(theta: f64, rows: usize, cols: usize, pitch: f64) -> Camera {
    let (s, c) = theta.sin_cos();
    let (dso, dsd) = (400.0, 600.0);
    Camera {
        projection: Projection::Cone,
        rotation: [[-s, c, 0.0], [0.0, 0.0, -1.0], [-c, -s, 0.0]],
        translation: [0.0, 0.0, dso],
        fx: dsd / pitch,
        fy: dsd / pitch,
        cx: (cols as f64 - 1.0) / 2.0,
        cy: (rows as f64 - 1.0) / 2.0,
        rows,
        cols,
        sdd: dsd,
    }
}

pub(crate) fn parallel(theta: f64, rows: usize, cols: usize, pitch: f64) -> Camera {
    Camera {
        projection: Projection::Parallel,
        fx: 1.0 / pitch,
        fy: 1.0 / pitch,
        ..cone(theta, rows, cols, pitch)
    }
}

/// Untiled f64 reference projector: every Gaussian against every pixel.
fn reference_project(
    x: &[f64],
    k: usize,
    m: usize,
    screen: &[f64],
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f64> {
    let geom = |i: usize| GaussianGeom {
        mean: [x[3 * i], x[3 * i + 1], x[3 * i + 2]],
        scale: [x[3 * k + 3 * i], x[3 * k + 3 * i + 1], x[3 * k + 3 * i + 2]],
        quat: [
            x[6 * k + 4 * i],
            x[6 * k + 4 * i + 1],
            x[6 * k + 4 * i + 2],
            x[6 * k + 4 * i + 3],
        ],
    };
    let dens = |i: usize, c: usize| x[10 * k + m * i + c];
    let plane = cams[0].rows * cams[0].cols;
    let mut out = vec![0.0; cams.len() * m * plane];
    let cut2 = opts.cutoff * opts.cutoff;
    for (v, cam) in cams.iter().enumerate() {
        for i in 0..k {
            let off = [screen[2 * (v * k + i)], screen[2 * (v * k + i) + 1]];
            for row in 0..cam.rows {
                for col in 0..cam.cols {
                    let val = match opts.mode {
                        ProjectionMode::Affine => {
                            let Some(s) = gm::splat(
                                &geom(i),
                                cam,
                                off,
                                opts.cutoff,
                                opts.near_fraction * cam.sdd,
                            ) else {
                                continue;
                            };
                            let q = s.conic.eval(col as f64 - s.mean[0], row as f64 - s.mean[1]);
                            if q > cut2 {
                                continue;
                            }
                            s.mu * (-0.5 * q).exp()
                        }
                        ProjectionMode::Exact => {
                            let Some(s) = gm::exact_splat(&geom(i), cam, off, opts.cutoff) else {
                                continue;
                            };
                            let (o, d, len) = gm::camera_ray(cam, col as f64, row as f64);
                            let Some(rt) = gm::ray_terms(&s.ray_gaussian, o, d) else {
                                continue;
                            };
                            if rt.q > cut2 {
                                continue;
                            }
                            gm::line_integral_terms(&rt, len)
                        }
                    };
                    for c in 0..m {
                        out[(v * m + c) * plane + row * cam.cols + col] += dens(i, c) * val;
                    }
                }
            }
        }
    }
    out
}

/// `max |a − b| ≤ tol · max |a|` (and `a` not all zero).
fn assert_close_to_scale(what: &str, a: &[f32], b: &[f32], tol: f64) {
    assert_eq!(a.len(), b.len(), "{what}");
    let scale = a.iter().fold(0.0f64, |m, &v| m.max((v as f64).abs()));
    assert!(scale > 0.0, "{what}: all zero");
    let err = a
        .iter()
        .zip(b)
        .fold(0.0f64, |m, (&x, &y)| m.max((x as f64 - y as f64).abs()));
    assert!(err <= tol * scale, "{what}: {:e}", err / scale);
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |a, b| a.max(b.abs()))
}

#[test]
fn isotropic_gaussian_on_the_central_ray() {
    // Centre pixel = ρ·√(2π)·s to 1e-5 relative, cone and parallel, affine and exact.
    for cam in [cone(0.3, 33, 33, 1.0), parallel(0.3, 33, 33, 1.0)] {
        for mode in [ProjectionMode::Affine, ProjectionMode::Exact] {
            let (rho, s) = (0.37f32, 2.5f32);
            let p = Params {
                means: vec![0.0; 3],
                scales: vec![s; 3],
                rotations: vec![1.0, 0.0, 0.0, 0.0],
                densities: vec![rho],
                channels: 1,
            };
            let opts = ProjectOptions {
                mode,
                ..Default::default()
            };
            let img = project_forward(&p.slices(), &[0.0; 2], &[cam], &opts);
            let centre = img[16 * 33 + 16] as f64;
            let want = rho as f64 * SQRT_2PI * s as f64;
            let err = (centre - want).abs() / want;
            eprintln!(
                "{:?} {mode:?}: centre {centre:.7} vs ρ√(2π)s {want:.7}, rel err {err:.1e}",
                cam.projection
            );
            assert!(err < 1e-5);
        }
    }
}

#[test]
fn turned_detectors_integrate_along_their_own_rays() {
    // A view as per-view vectors make it: the detector spun in its plane (0.2 rad) and tilted
    // about its rows (0.1 rad), the principal point off-centre, so no camera axis lies along a
    // world axis. An isotropic Gaussian's line integral along any ray is
    // ρ·√(2π)·σ·exp(−d²/2σ²), d its distance from the mean (the ray's ends lie ≥ 150 mm, 60σ,
    // away). Exact mode within 1e-5 of the peak (f32 rounding; measured 5e-8); affine within
    // 1e-3, below its drift bound for σ ≈ 2 mm (`affine_versus_exact_drift`; measured 1.5e-4).
    let turn = |r: [[f64; 3]; 3]| {
        let (sa, ca) = 0.2f64.sin_cos();
        let (sb, cb) = 0.1f64.sin_cos();
        let mix = |a: [f64; 3], b: [f64; 3], p: f64, q: f64| [0, 1, 2].map(|k| p * a[k] + q * b[k]);
        let x = mix(r[0], r[1], ca, sa);
        let y = mix(r[0], r[1], -sa, ca);
        [mix(x, r[2], cb, -sb), y, mix(x, r[2], sb, cb)]
    };
    let (rho, sigma) = (0.37f64, 2.5f64);
    let mean = [4.0f64, -3.0, 5.0];
    for base in [cone(0.3, 33, 33, 1.0), parallel(0.3, 33, 33, 1.0)] {
        let mut cam = base;
        cam.rotation = turn(cam.rotation);
        cam.cx += 1.3;
        cam.cy -= 0.8;
        for (mode, tol) in [
            (ProjectionMode::Exact, 1e-5),
            (ProjectionMode::Affine, 1e-3),
        ] {
            let p = Params {
                means: mean.map(|v| v as f32).to_vec(),
                scales: vec![sigma as f32; 3],
                rotations: vec![1.0, 0.0, 0.0, 0.0],
                densities: vec![rho as f32],
                channels: 1,
            };
            let opts = ProjectOptions {
                mode,
                cutoff: 6.0,
                ..Default::default()
            };
            let img = project_forward(&p.slices(), &[0.0; 2], &[cam], &opts);
            let want: Vec<f32> = (0..cam.rows * cam.cols)
                .map(|i| {
                    let ray = cam.pixel_ray((i % cam.cols) as f64, (i / cam.cols) as f64);
                    let o = [0, 1, 2].map(|k| mean[k] - ray.origin[k]);
                    let t: f64 = (0..3).map(|k| o[k] * ray.direction[k]).sum();
                    let d2 = o.iter().map(|x| x * x).sum::<f64>() - t * t;
                    (rho * SQRT_2PI * sigma * (-0.5 * d2 / (sigma * sigma)).exp()) as f32
                })
                .collect();
            let what = format!("{:?} {mode:?}", cam.projection);
            assert_close_to_scale(&what, &want, &img, tol);
        }
    }
}

#[test]
fn forward_matches_the_per_pixel_reference() {
    // Many Gaussians spanning band borders and several lane blocks, two channels, two views,
    // random screen offsets; a detector whose width is not a multiple of the lane block.
    let p = Params::random(60, 2, 20.0, (0.8, 4.0), 7);
    let k = 60;
    let cams = [cone(0.2, 40, 37, 0.9), cone(1.9, 40, 37, 0.9)];
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let screen: Vec<f32> = (0..2 * k * 2)
        .map(|_| rng.random_range(-0.5..0.5))
        .collect();
    let screen64: Vec<f64> = screen.iter().map(|&v| v as f64).collect();
    for opts in [
        ProjectOptions::default(),
        ProjectOptions::exact(),
        ProjectOptions {
            cutoff: 5.0,
            ..Default::default()
        },
    ] {
        let img = project_forward(&p.slices(), &screen, &cams, &opts);
        let want = reference_project(&p.flat(), k, 2, &screen64, &cams, &opts);
        let scale = max_abs(&want);
        let err = img
            .iter()
            .zip(&want)
            .fold(0.0f64, |a, (x, y)| a.max((*x as f64 - y).abs()))
            / scale;
        assert!(err < 1e-5, "{opts:?}: {err:e}");
    }
    let pp = [parallel(0.2, 40, 37, 0.9), parallel(2.5, 40, 37, 0.9)];
    let img = project_forward(&p.slices(), &screen, &pp, &ProjectOptions::default());
    let want = reference_project(&p.flat(), k, 2, &screen64, &pp, &ProjectOptions::default());
    let err = img
        .iter()
        .zip(&want)
        .fold(0.0f64, |a, (x, y)| a.max((*x as f64 - y).abs()))
        / max_abs(&want);
    assert!(err < 1e-5, "parallel: {err:e}");
}

#[test]
fn simd_dispatch_matches_baseline() {
    // The AVX2 build of the row loops differs from the baseline only by fused multiply-adds (in
    // the quadratic form, the exp polynomial and the backward's channel and dy² sums): per pixel
    // a relative change of a few f32 ulps (|Δq| ≲ 2⁻²³ q with q ≤ cut² = 9 moves exp(−q/2) by
    // ≲ 6e-7 relatively), so images agree to 2e-6 of their peak and gradients (sums of such
    // terms, with cancellation) to 2e-5 of their largest entry. The detector (37 × 40) has
    // partial edge tiles; two channels exercise the channel loops, one channel its own path.
    let k = 80;
    let cams = [cone(0.7, 40, 37, 0.9), parallel(2.1, 40, 37, 0.9)];
    for channels in [2, 1] {
        let p = Params::random(k, channels, 20.0, (0.5, 4.0), 11);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let screen: Vec<f32> = (0..2 * k * 2)
            .map(|_| rng.random_range(-0.5..0.5))
            .collect();
        let grad: Vec<f32> = (0..2 * channels * 40 * 37)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let opts = ProjectOptions::default();
        let run = |baseline: bool| {
            prism_kernel::simd::force_baseline(baseline);
            let img = project_forward(&p.slices(), &screen, &cams, &opts);
            let grads = project_backward(&p.slices(), &screen, &cams, &opts, &grad);
            prism_kernel::simd::force_baseline(false);
            (img, grads)
        };
        let (img_base, g_base) = run(true);
        let (img, g) = run(false);
        let close = |name: &str, a: &[f32], b: &[f32], tol: f64| {
            assert_close_to_scale(&format!("{name} (M = {channels})"), a, b, tol)
        };
        close("image", &img_base, &img, 2e-6);
        close("means", &g_base.means, &g.means, 2e-5);
        close("scales", &g_base.scales, &g.scales, 2e-5);
        close("rotations", &g_base.rotations, &g.rotations, 2e-5);
        close("densities", &g_base.densities, &g.densities, 2e-5);
        close("screen", &g_base.screen, &g.screen, 2e-5);
    }
}

#[test]
fn prepared_state_reproduces_the_recomputed_passes() {
    // The prepared records are the f32 pixel splats themselves (boxes exact below 2²⁰), and the
    // chain rule recomputes its f64 splat either way: results are bit-identical. A buffer of
    // the wrong length is ignored; one made for a larger detector is clamped, never indexed
    // out of range.
    let k = 50;
    let p = Params::random(k, 2, 20.0, (0.5, 4.0), 17);
    let cams = [cone(0.3, 40, 37, 0.9), cone(1.9, 40, 37, 0.9)];
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let screen: Vec<f32> = (0..2 * k * 2)
        .map(|_| rng.random_range(-0.5..0.5))
        .collect();
    let grad: Vec<f32> = (0..2 * 2 * 40 * 37)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let opts = ProjectOptions::default();
    let g = p.slices();
    let prepared = project_prepare(&g, &screen, &cams, &opts);
    assert_eq!(prepared.len(), 2 * k * PREPARED_WIDTH);
    assert!(prepared.iter().any(|&v| v != 0.0));
    let img = project_forward(&g, &screen, &cams, &opts);
    let grads = project_backward(&g, &screen, &cams, &opts, &grad);
    assert!(img.iter().any(|&v| v != 0.0));
    assert_eq!(
        project_forward_prepared(&g, &screen, &prepared, &cams, &opts),
        img
    );
    assert_eq!(
        project_backward_prepared(&g, &screen, &prepared, &cams, &opts, &grad),
        grads
    );
    let short = &prepared[..prepared.len() - 1];
    assert_eq!(
        project_forward_prepared(&g, &screen, short, &cams, &opts),
        img
    );
    let big = [cone(0.3, 90, 80, 0.9), cone(1.9, 90, 80, 0.9)];
    let foreign = project_prepare(&g, &screen, &big, &opts);
    let img2 = project_forward_prepared(&g, &screen, &foreign, &cams, &opts);
    assert_eq!(img2.len(), img.len());
    assert!(img2.iter().all(|v| v.is_finite()));
}

#[test]
fn affine_versus_exact_drift() {
    // TIGRE-like geometry (DSO 1000, DSD 1536, 1 mm voxels), an anisotropic Gaussian 60–80 mm off
    // the axis; generous cut-off so both modes keep their full tails. The affine model's error
    // relative to the peak must stay below the drift of "all rays parallel to the central ray"
    // measured for this geometry (7.8e-4 at σ≈2 mm, 3.7e-3 at σ≈10 mm): we require ≤ 7.8e-4 for
    // σ = 1 and ≤ 3.7e-3 for σ = 5 and 10 (σ is the largest of the three axis scales).
    let (dso, dsd, pitch) = (1000.0, 1536.0, 0.8);
    for (sigma, bound) in [(1.0f32, 7.8e-4), (5.0, 3.7e-3), (10.0, 3.7e-3)] {
        let n = 32usize;
        let pitch = pitch * (sigma as f64).max(1.0) * 0.5;
        let mut cam = cone(0.0, n, n, pitch);
        cam.translation = [0.0, 0.0, dso];
        cam.fx = dsd / pitch;
        cam.fy = dsd / pitch;
        cam.sdd = dsd;
        let mean = [20.0f32, 80.0, 60.0];
        // Centre the detector window on the Gaussian's projection.
        let c = cam.to_camera(mean.map(|v| v as f64));
        cam.cx = (n as f64 - 1.0) / 2.0 - cam.fx * c[0] / c[2];
        cam.cy = (n as f64 - 1.0) / 2.0 - cam.fy * c[1] / c[2];
        let p = Params {
            means: mean.to_vec(),
            scales: vec![sigma, 0.6 * sigma, 0.8 * sigma],
            rotations: vec![0.9, 0.2, -0.3, 0.1],
            densities: vec![1.0],
            channels: 1,
        };
        let affine = project_forward(
            &p.slices(),
            &[0.0; 2],
            &[cam],
            &ProjectOptions {
                cutoff: 7.0,
                ..Default::default()
            },
        );
        let exact = project_forward(
            &p.slices(),
            &[0.0; 2],
            &[cam],
            &ProjectOptions {
                cutoff: 7.0,
                ..ProjectOptions::exact()
            },
        );
        let peak = exact.iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
        let err = affine
            .iter()
            .zip(&exact)
            .fold(0.0f64, |a, (x, y)| a.max((*x - *y).abs() as f64))
            / peak;
        eprintln!("σ = {sigma} mm: max |affine − exact| / peak = {err:.2e} (bound {bound:.1e})");
        assert!(err < bound, "σ = {sigma}: {err:e}");
    }
}

/// Loss `Σ r·image` through the f64 reference, for central differences.
fn ref_loss(
    x: &[f64],
    k: usize,
    m: usize,
    screen: &[f64],
    cams: &[Camera],
    opts: &ProjectOptions,
    r: &[f32],
) -> f64 {
    reference_project(x, k, m, screen, cams, opts)
        .iter()
        .zip(r)
        .map(|(a, b)| a * *b as f64)
        .sum()
}

fn check_project_gradients(p: &Params, cams: &[Camera], opts: &ProjectOptions, seed: u64) {
    let k = p.means.len() / 3;
    let m = p.channels;
    let plane = cams[0].rows * cams[0].cols;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let r: Vec<f32> = (0..cams.len() * m * plane)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let screen: Vec<f32> = (0..2 * k * cams.len())
        .map(|_| rng.random_range(-0.3..0.3))
        .collect();
    let screen64: Vec<f64> = screen.iter().map(|&v| v as f64).collect();
    let grads = project_backward(&p.slices(), &screen, cams, opts, &r);
    let x0 = p.flat();
    let h = 1e-6;
    let fd = |x: &[f64], s: &[f64], i: usize, on_screen: bool| {
        let (mut xp, mut xm, mut sp, mut sm) = (x.to_vec(), x.to_vec(), s.to_vec(), s.to_vec());
        if on_screen {
            sp[i] += h;
            sm[i] -= h;
        } else {
            xp[i] += h;
            xm[i] -= h;
        }
        (ref_loss(&xp, k, m, &sp, cams, opts, &r) - ref_loss(&xm, k, m, &sm, cams, opts, &r))
            / (2.0 * h)
    };
    let groups: [(&str, &[f32], usize); 5] = [
        ("means", &grads.means, 0),
        ("scales", &grads.scales, 3 * k),
        ("rotations", &grads.rotations, 6 * k),
        ("densities", &grads.densities, 10 * k),
        ("screen", &grads.screen, usize::MAX),
    ];
    for (name, analytic, start) in groups {
        let numeric: Vec<f64> = (0..analytic.len())
            .map(|i| {
                if start == usize::MAX {
                    fd(&x0, &screen64, i, true)
                } else {
                    fd(&x0, &screen64, start + i, false)
                }
            })
            .collect();
        // f32 pixel sums of ≲ 10³ terms: relative rounding ≲ 1e-5 of the group's largest entry.
        let scale = max_abs(&numeric);
        assert!(scale > 0.0, "{name}: zero gradient — test is vacuous");
        for (i, (a, n)) in analytic.iter().zip(&numeric).enumerate() {
            assert!(
                (*a as f64 - n).abs() <= 2e-4 * scale,
                "{:?} {:?} {name}[{i}]: analytic {a} vs central difference {n} (scale {scale})",
                cams[0].projection,
                opts.mode
            );
        }
    }
}

#[test]
fn projection_gradients_match_central_differences() {
    // Anisotropic rotated Gaussians, two views, two channels. Cut-off 8σ puts the cut where the
    // Gaussian is e^{−32} ≈ 1e-14 of its peak, so the loss is smooth at the f64 FD resolution.
    let p = Params::random(3, 2, 6.0, (1.5, 4.0), 11);
    for cams in [
        [cone(0.4, 20, 18, 1.2), cone(2.1, 20, 18, 1.2)],
        [parallel(0.4, 20, 18, 1.0), parallel(2.1, 20, 18, 1.0)],
    ] {
        for mode in [ProjectionMode::Affine, ProjectionMode::Exact] {
            let opts = ProjectOptions {
                mode,
                cutoff: 8.0,
                ..Default::default()
            };
            check_project_gradients(&p, &cams, &opts, 5);
        }
    }
    // One channel takes its own path in the affine pixel kernel (ρ factored out of the sums).
    let p = Params::random(3, 1, 6.0, (1.5, 4.0), 12);
    let opts = ProjectOptions {
        cutoff: 8.0,
        ..Default::default()
    };
    check_project_gradients(&p, &[cone(0.4, 20, 18, 1.2)], &opts, 6);
}

#[test]
fn exact_gradients_near_the_source() {
    // A Gaussian 20 mm in front of the source: the segment's erf factors carry the gradient.
    let mut p = Params::random(2, 1, 3.0, (2.0, 3.0), 13);
    let cam = cone(0.0, 12, 12, 6.0);
    p.means[0] = 380.0; // DSO 400 along +x at θ = 0
    check_project_gradients(
        &p,
        &[cam],
        &ProjectOptions {
            cutoff: 8.0,
            ..ProjectOptions::exact()
        },
        9,
    );
}

#[test]
fn voxelize_matches_direct_evaluation() {
    let p = Params::random(40, 2, 12.0, (0.7, 5.0), 21);
    // A 32³ TV-patch-like sub-box with anisotropic voxels and an off-centre grid.
    let grid = VoxelGrid {
        dims: [32, 30, 28],
        voxel: [0.8, 0.9, 1.1],
        offset: [1.5, -2.0, 0.7],
    };
    let vol = voxelize_forward(&p.slices(), &grid, &VoxelizeOptions::default());
    let want = reference_voxelize_f64(&p.flat(), 40, 2, &grid, 3.0);
    let mut worst = 0.0f64;
    for (a, b) in vol.iter().zip(&want) {
        worst = worst.max((*a as f64 - b).abs() / b.abs().max(1e-30));
    }
    // Per voxel, relative: f32 evaluation of ≤ a few dozen terms.
    eprintln!("voxelize vs direct: max relative error {worst:.1e}");
    assert!(worst < 1e-5, "{worst:e}");
}

#[test]
fn voxelize_gradients_match_central_differences() {
    // Two channels exercise the channel loops, one channel its own path; the grid ends inside a
    // lane block and a slab, and the boxes span several blocks and more than 64 rows (a flush).
    for m in [2, 1] {
        let k = 3;
        let p = Params::random(k, m, 3.0, (1.0, 2.5), 31);
        let grid = VoxelGrid {
            dims: [14, 12, 10],
            voxel: [0.7, 0.8, 0.9],
            offset: [0.3, -0.2, 0.1],
        };
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let r: Vec<f32> = (0..m * grid.len())
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let opts = VoxelizeOptions { cutoff: 8.0 };
        let grads = voxelize_backward(&p.slices(), &grid, &opts, &r);
        let loss = |x: &[f64]| -> f64 {
            reference_voxelize_f64(x, k, m, &grid, 8.0)
                .iter()
                .zip(&r)
                .map(|(a, b)| a * *b as f64)
                .sum()
        };
        let x0 = p.flat();
        let h = 1e-6;
        let analytic: Vec<f32> = grads
            .means
            .iter()
            .chain(&grads.scales)
            .chain(&grads.rotations)
            .chain(&grads.densities)
            .copied()
            .collect();
        let names = [
            ("means", 0, 3 * k),
            ("scales", 3 * k, 6 * k),
            ("rotations", 6 * k, 10 * k),
            ("densities", 10 * k, (10 + m) * k),
        ];
        for (name, lo, hi) in names {
            let numeric: Vec<f64> = (lo..hi)
                .map(|i| {
                    let (mut a, mut b) = (x0.clone(), x0.clone());
                    a[i] += h;
                    b[i] -= h;
                    (loss(&a) - loss(&b)) / (2.0 * h)
                })
                .collect();
            let scale = max_abs(&numeric);
            for (j, n) in numeric.iter().enumerate() {
                let a = analytic[lo + j] as f64;
                assert!(
                    (a - n).abs() <= 2e-4 * scale,
                    "{name}[{j}] (M = {m}): analytic {a} vs central difference {n}"
                );
            }
        }
    }
}

/// A small patch among many Gaussians (a TV patch): the passes walk only the Gaussians near it,
/// so the patch's volume and every near Gaussian's gradient row are bit for bit those of the
/// near Gaussians alone, and every other row is exactly zero.
#[test]
fn a_patch_sees_only_the_gaussians_near_it() {
    let m = 2;
    let k = 300;
    let p = Params::random(k, m, 12.0, (0.3, 1.5), 51);
    let grid = VoxelGrid {
        dims: [9, 8, 7],
        voxel: [0.8, 0.9, 1.0],
        offset: [4.0, -3.0, 2.5],
    };
    let opts = VoxelizeOptions::default();
    // Near: the f64 reference gives the Gaussian alone a value somewhere on the grid.
    let near: Vec<usize> = (0..k)
        .filter(|&i| {
            let one = p.select(&[i]);
            reference_voxelize_f64(&one.flat(), 1, m, &grid, opts.cutoff)
                .iter()
                .any(|&v| v != 0.0)
        })
        .collect();
    assert!(
        (5..k / 4).contains(&near.len()),
        "{} near Gaussians: not a patch among many",
        near.len()
    );
    let alone = p.select(&near);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let r: Vec<f32> = (0..m * grid.len())
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        bits(&voxelize_forward(&p.slices(), &grid, &opts)),
        bits(&voxelize_forward(&alone.slices(), &grid, &opts))
    );
    let all = voxelize_backward(&p.slices(), &grid, &opts, &r);
    let few = voxelize_backward(&alone.slices(), &grid, &opts, &r);
    let rows = [
        (&all.means, &few.means, 3),
        (&all.scales, &few.scales, 3),
        (&all.rotations, &few.rotations, 4),
        (&all.densities, &few.densities, m),
    ];
    for (a, f, w) in rows {
        let mut j = 0;
        for i in 0..k {
            let row = &a[w * i..w * (i + 1)];
            if near.get(j) == Some(&i) {
                assert_eq!(bits(row), bits(&f[w * j..w * (j + 1)]), "Gaussian {i}");
                assert!(
                    row.iter().any(|&v| v != 0.0),
                    "near Gaussian {i} has no gradient"
                );
                j += 1;
            } else {
                assert!(row.iter().all(|&v| v == 0.0), "far Gaussian {i}: {row:?}");
            }
        }
    }
}

#[test]
fn voxelize_simd_dispatch_matches_baseline() {
    // As for the projection: the AVX2 path differs from the baseline only by FMA rounding.
    let grid = VoxelGrid {
        dims: [21, 18, 13],
        voxel: [0.8, 0.9, 1.1],
        offset: [0.5, -0.4, 0.2],
    };
    for m in [2, 1] {
        let k = 60;
        let p = Params::random(k, m, 8.0, (0.5, 3.0), 41);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let r: Vec<f32> = (0..m * grid.len())
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let opts = VoxelizeOptions::default();
        let run = |baseline: bool| {
            prism_kernel::simd::force_baseline(baseline);
            let vol = voxelize_forward(&p.slices(), &grid, &opts);
            let grads = voxelize_backward(&p.slices(), &grid, &opts, &r);
            prism_kernel::simd::force_baseline(false);
            (vol, grads)
        };
        let (v0, g0) = run(true);
        let (v1, g1) = run(false);
        let close = |name: &str, a: &[f32], b: &[f32], tol: f64| {
            assert_close_to_scale(&format!("{name} (M = {m})"), a, b, tol)
        };
        close("volume", &v0, &v1, 2e-6);
        close("means", &g0.means, &g1.means, 2e-5);
        close("scales", &g0.scales, &g1.scales, 2e-5);
        close("rotations", &g0.rotations, &g1.rotations, 2e-5);
        close("densities", &g0.densities, &g1.densities, 2e-5);
    }
}

/// Untiled f64 voxelizer: every Gaussian at every voxel centre, parameters as in `Params::flat`.
pub(crate) fn reference_voxelize_f64(
    x: &[f64],
    k: usize,
    m: usize,
    grid: &VoxelGrid,
    cutoff: f64,
) -> Vec<f64> {
    let [nx, ny, nz] = grid.dims;
    let mut out = vec![0.0; m * grid.len()];
    for i in 0..k {
        let geom = GaussianGeom {
            mean: [x[3 * i], x[3 * i + 1], x[3 * i + 2]],
            scale: [x[3 * k + 3 * i], x[3 * k + 3 * i + 1], x[3 * k + 3 * i + 2]],
            quat: [
                x[6 * k + 4 * i],
                x[6 * k + 4 * i + 1],
                x[6 * k + 4 * i + 2],
                x[6 * k + 4 * i + 3],
            ],
        };
        let sh = gm::shape3(&geom).unwrap();
        for z in 0..nz {
            for y in 0..ny {
                for xx in 0..nx {
                    let c = [grid.centre(0, xx), grid.centre(1, y), grid.centre(2, z)];
                    let d = [
                        c[0] - geom.mean[0],
                        c[1] - geom.mean[1],
                        c[2] - geom.mean[2],
                    ];
                    let q = gm::dot(d, gm::mat_vec(&sh.prec, d));
                    if q <= cutoff * cutoff {
                        for ch in 0..m {
                            out[ch * grid.len() + (z * ny + y) * nx + xx] +=
                                x[10 * k + m * i + ch] * (-0.5 * q).exp();
                        }
                    }
                }
            }
        }
    }
    out
}

#[test]
fn fast_exp_is_accurate_and_guarded() {
    let mut worst = 0.0f64;
    let mut x = -87.0f32;
    while x <= 0.0 {
        let want = (x as f64).exp();
        worst = worst.max((exp_neg(x) as f64 - want).abs() / want);
        x += 0.0137;
    }
    assert!(worst < 1e-6, "{worst:e}");
    assert_eq!(exp_neg(0.0), 1.0);
    assert!(exp_neg(f32::NEG_INFINITY) < 1e-37);
    assert!(exp_neg(-1e30) >= 0.0);
    assert!(exp_neg(f32::NAN).is_nan());
}
