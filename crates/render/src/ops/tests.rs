//! The Burn ops end to end: autodiff registration on Flex and NdArray, several views and
//! channels, input validation, and every stiff case of the issue (finite outputs and gradients).

use super::*;
use crate::cpu::tests::{Params, cone, parallel};
use crate::cpu::{project_backward, voxelize_backward};
use crate::options::ProjectionMode;
use burn::tensor::{Device, TensorData};

fn devices() -> Vec<Device> {
    [
        #[cfg(feature = "flex")]
        Device::flex(),
        #[cfg(feature = "ndarray")]
        Device::ndarray(),
    ]
    .into_iter()
    .collect()
}

pub(crate) fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .into_vec::<f32>()
        .expect("f32 data")
}

pub(crate) fn tensors(p: &Params, device: &Device, track: bool) -> Gaussians {
    let k = p.means.len() / 3;
    let mk = |v: &Vec<f32>, c: usize| {
        let t = Tensor::<2>::from_data(TensorData::new(v.clone(), [k, c]), device);
        if track { t.require_grad() } else { t }
    };
    Gaussians {
        means: mk(&p.means, 3),
        scales: mk(&p.scales, 3),
        rotations: mk(&p.rotations, 4),
        densities: mk(&p.densities, p.channels),
    }
}

pub(crate) fn weights(n: usize, seed: u32) -> Vec<f32> {
    // Deterministic, sign-changing upstream gradient.
    (0..n)
        .map(|i| {
            (((i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8) as f32 / 16777216.0)
                - 0.5
        })
        .collect()
}

fn assert_close(a: &[f32], b: &[f32], tol: f32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: length");
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-30);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!((x - y).abs() <= tol * scale, "{what}[{i}]: {x} vs {y}");
    }
}

#[test]
fn autodiff_reaches_every_parameter_and_matches_the_kernel() {
    let p = Params::random(12, 2, 10.0, (1.0, 4.0), 1);
    let cams = vec![cone(0.1, 24, 20, 1.0), cone(1.3, 24, 20, 1.0)];
    for device in devices() {
        for mode in [ProjectionMode::Affine, ProjectionMode::Exact] {
            let opts = ProjectOptions {
                mode,
                ..Default::default()
            };
            let ad = device.clone().autodiff();
            let g = tensors(&p, &ad, true);
            let probe = screen_probe(&g, cams.len());
            let img = project(&g, &cams, Some(&probe), &opts).unwrap();
            assert_eq!(img.dims(), [2, 2, 24, 20]);
            let r = weights(2 * 2 * 24 * 20, 3);
            let rt = Tensor::<4>::from_data(TensorData::new(r.clone(), [2, 2, 24, 20]), &ad);
            let grads = (img * rt).sum().backward();
            let want = project_backward(&p.slices(), &[0.0; 2 * 12 * 2], &cams, &opts, &r);
            assert_close(
                &to_vec(g.means.grad(&grads).unwrap()),
                &want.means,
                1e-6,
                "means",
            );
            assert_close(
                &to_vec(g.scales.grad(&grads).unwrap()),
                &want.scales,
                1e-6,
                "scales",
            );
            assert_close(
                &to_vec(g.rotations.grad(&grads).unwrap()),
                &want.rotations,
                1e-6,
                "rotations",
            );
            assert_close(
                &to_vec(g.densities.grad(&grads).unwrap()),
                &want.densities,
                1e-6,
                "densities",
            );
            let sg = probe.grad(&grads).unwrap();
            assert_close(&to_vec(sg.clone()), &want.screen, 1e-6, "screen");
            // The densification statistic is Σ_views ‖∂L/∂mean2D‖.
            let stat = to_vec(screen_grad_norm(&sg));
            for i in 0..12 {
                let n: f32 = (0..2)
                    .map(|v| {
                        (want.screen[2 * (v * 12 + i)].powi(2)
                            + want.screen[2 * (v * 12 + i) + 1].powi(2))
                        .sqrt()
                    })
                    .sum();
                assert!((stat[i] - n).abs() <= 1e-5 * n.max(1e-20), "stat[{i}]");
            }
        }
    }
}

#[test]
fn partial_tracking_and_plain_devices() {
    let p = Params::random(5, 1, 8.0, (1.0, 3.0), 2);
    let cams = vec![parallel(0.5, 16, 16, 1.0)];
    for device in devices() {
        let ad = device.clone().autodiff();
        let mut g = tensors(&p, &ad, false);
        g.densities = g.densities.require_grad();
        let img = project(&g, &cams, None, &ProjectOptions::default()).unwrap();
        let grads = img.sum().backward();
        assert!(g.means.grad(&grads).is_none());
        assert!(g.densities.grad(&grads).is_some());
        // No autodiff at all: plain forward.
        let plain = project(
            &tensors(&p, &device, false),
            &cams,
            None,
            &ProjectOptions::default(),
        )
        .unwrap();
        assert_eq!(plain.dims(), [1, 1, 16, 16]);
    }
}

#[test]
fn several_views_and_channels_equal_separate_calls() {
    let p = Params::random(20, 3, 10.0, (1.0, 4.0), 5);
    let cams = vec![
        cone(0.0, 16, 24, 1.0),
        cone(0.9, 16, 24, 1.0),
        cone(2.2, 16, 24, 1.0),
    ];
    let device = devices().remove(0);
    let g = tensors(&p, &device, false);
    let all = to_vec(project(&g, &cams, None, &ProjectOptions::default()).unwrap());
    let plane = 16 * 24;
    for (v, cam) in cams.iter().enumerate() {
        for c in 0..3 {
            let mut one = p.clone();
            one.densities = (0..20).map(|i| p.densities[3 * i + c]).collect();
            one.channels = 1;
            let img = to_vec(
                project(
                    &tensors(&one, &device, false),
                    &[*cam],
                    None,
                    &ProjectOptions::default(),
                )
                .unwrap(),
            );
            let off = (v * 3 + c) * plane;
            assert_close(&all[off..off + plane], &img, 0.0, "view/channel");
        }
    }
}

#[test]
fn voxelize_autodiff_matches_the_kernel() {
    let p = Params::random(10, 2, 6.0, (0.8, 3.0), 8);
    let grid = VoxelGrid {
        dims: [12, 10, 8],
        voxel: [1.0, 1.1, 0.9],
        offset: [0.5, 0.0, -0.5],
    };
    for device in devices() {
        let ad = device.clone().autodiff();
        let g = tensors(&p, &ad, true);
        let vol = voxelize(&g, &grid, &VoxelizeOptions::default()).unwrap();
        assert_eq!(vol.dims(), [2, 8, 10, 12]);
        let r = weights(2 * grid.len(), 9);
        let rt = Tensor::<4>::from_data(TensorData::new(r.clone(), [2, 8, 10, 12]), &ad);
        let grads = (vol * rt).sum().backward();
        let want = voxelize_backward(&p.slices(), &grid, &VoxelizeOptions::default(), &r);
        assert_close(
            &to_vec(g.means.grad(&grads).unwrap()),
            &want.means,
            1e-6,
            "means",
        );
        assert_close(
            &to_vec(g.scales.grad(&grads).unwrap()),
            &want.scales,
            1e-6,
            "scales",
        );
        assert_close(
            &to_vec(g.rotations.grad(&grads).unwrap()),
            &want.rotations,
            1e-6,
            "rotations",
        );
        assert_close(
            &to_vec(g.densities.grad(&grads).unwrap()),
            &want.densities,
            1e-6,
            "densities",
        );
    }
}

#[test]
fn bad_inputs_name_their_field() {
    let p = Params::random(2, 1, 1.0, (1.0, 2.0), 1);
    let device = devices().remove(0);
    let g = tensors(&p, &device, false);
    let cam = cone(0.0, 8, 8, 1.0);
    let err = project(&g, &[], None, &ProjectOptions::default()).unwrap_err();
    assert_eq!(err.field, "cameras");
    let err = project(
        &g,
        &[cam, cone(0.0, 8, 9, 1.0)],
        None,
        &ProjectOptions::default(),
    )
    .unwrap_err();
    assert_eq!(err.field, "cameras[1].rows/cols");
    let err = project(
        &g,
        &[Camera {
            fx: f64::NAN,
            ..cam
        }],
        None,
        &ProjectOptions::default(),
    )
    .unwrap_err();
    assert_eq!(err.field, "cameras[0].fx");
    let err = project(
        &g,
        &[cam],
        None,
        &ProjectOptions {
            cutoff: 0.0,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert_eq!(err.field, "cutoff");
    let bad = Gaussians {
        scales: Tensor::<2>::zeros([2, 2], &device),
        ..g.clone()
    };
    assert_eq!(
        project(&bad, &[cam], None, &ProjectOptions::default())
            .unwrap_err()
            .field,
        "scales"
    );
    let bad = Gaussians {
        densities: Tensor::<2>::zeros([3, 1], &device),
        ..g.clone()
    };
    assert_eq!(
        project(&bad, &[cam], None, &ProjectOptions::default())
            .unwrap_err()
            .field,
        "densities"
    );
    let probe = Tensor::<3>::zeros([2, 2, 2], &device);
    assert_eq!(
        project(&g, &[cam], Some(&probe), &ProjectOptions::default())
            .unwrap_err()
            .field,
        "screen"
    );
    let grid = VoxelGrid {
        dims: [4, 0, 4],
        voxel: [1.0; 3],
        offset: [0.0; 3],
    };
    assert_eq!(
        voxelize(&g, &grid, &VoxelizeOptions::default())
            .unwrap_err()
            .field,
        "grid.dims.y"
    );
    let grid = VoxelGrid {
        dims: [4, 4, 4],
        voxel: [1.0, -1.0, 1.0],
        offset: [0.0; 3],
    };
    assert_eq!(
        voxelize(&g, &grid, &VoxelizeOptions::default())
            .unwrap_err()
            .field,
        "grid.voxel.y"
    );
}

/// One stiff scene: project (both modes, cone and parallel) and voxelize with autodiff; assert
/// finite outputs and gradients; returns the affine cone image and the volume.
fn run_stiff(p: &Params, cams: &[Camera]) -> (Vec<f32>, Vec<f32>) {
    let device = devices().remove(0).autodiff();
    let mut first = None;
    for mode in [ProjectionMode::Affine, ProjectionMode::Exact] {
        for cam_set in [
            cams.to_vec(),
            cams.iter()
                .map(|c| Camera {
                    projection: crate::Projection::Parallel,
                    fx: 0.5,
                    fy: 0.5,
                    ..*c
                })
                .collect(),
        ] {
            let g = tensors(p, &device, true);
            let probe = screen_probe(&g, cam_set.len());
            let img = project(
                &g,
                &cam_set,
                Some(&probe),
                &ProjectOptions {
                    mode,
                    ..Default::default()
                },
            )
            .unwrap();
            let vals = to_vec(img.clone());
            assert!(
                vals.iter().all(|v| v.is_finite()),
                "{mode:?}: non-finite image"
            );
            let grads = (img.clone() * img).sum().backward();
            for (name, t) in [
                ("means", &g.means),
                ("scales", &g.scales),
                ("rotations", &g.rotations),
                ("densities", &g.densities),
            ] {
                let gv = to_vec(t.grad(&grads).unwrap());
                assert!(
                    gv.iter().all(|v| v.is_finite()),
                    "{mode:?}: non-finite {name} gradient {gv:?}"
                );
            }
            assert!(
                to_vec(probe.grad(&grads).unwrap())
                    .iter()
                    .all(|v| v.is_finite())
            );
            first.get_or_insert(vals);
        }
    }
    let g = tensors(p, &device, true);
    let grid = VoxelGrid {
        dims: [16, 16, 16],
        voxel: [4.0; 3],
        offset: [0.0; 3],
    };
    let vol = voxelize(&g, &grid, &VoxelizeOptions::default()).unwrap();
    let vv = to_vec(vol.clone());
    assert!(vv.iter().all(|v| v.is_finite()), "non-finite volume");
    let grads = (vol.clone() * vol).sum().backward();
    for t in [&g.means, &g.scales, &g.rotations, &g.densities] {
        assert!(
            to_vec(t.grad(&grads).unwrap())
                .iter()
                .all(|v| v.is_finite()),
            "non-finite voxel gradient"
        );
    }
    (first.unwrap(), vv)
}

fn one(mean: [f32; 3], scale: [f32; 3], quat: [f32; 4], density: f32) -> Params {
    Params {
        means: mean.to_vec(),
        scales: scale.to_vec(),
        rotations: quat.to_vec(),
        densities: vec![density],
        channels: 1,
    }
}

fn stiff_cam() -> Vec<Camera> {
    // Volume ≈ 64 mm (16 voxels of 4 mm), 32² detector of 3 mm pixels.
    vec![cone(0.3, 32, 32, 3.0)]
}

#[test]
fn stiff_needles_and_sheets() {
    let q = [0.9, 0.2, -0.3, 0.25];
    for s in [
        [0.01, 100.0, 1.0],
        [100.0, 100.0, 0.01],
        [0.001, 10.0, 10.0],
    ] {
        let (img, vol) = run_stiff(&one([2.0, -3.0, 1.0], s, q, 1.0), &stiff_cam());
        assert!(
            img.iter().any(|v| *v > 0.0) || vol.iter().any(|v| *v > 0.0),
            "{s:?}: nothing rendered"
        );
    }
    // Axis-aligned needle seen end-on and sheet seen edge-on (θ = 0 looks along −x).
    let cam = vec![cone(0.0, 32, 32, 3.0)];
    run_stiff(
        &one([0.0; 3], [100.0, 0.01, 0.01], [1.0, 0.0, 0.0, 0.0], 1.0),
        &cam,
    );
    run_stiff(
        &one([0.0; 3], [100.0, 100.0, 0.01], [1.0, 0.0, 0.0, 0.0], 1.0),
        &cam,
    );
}

#[test]
fn stiff_tiny_and_huge_scales() {
    // 1e-7 and 1e2 of a 64 mm volume.
    run_stiff(
        &one([1.0, 1.0, 1.0], [6.4e-6; 3], [1.0, 0.0, 0.0, 0.0], 1.0),
        &stiff_cam(),
    );
    let (img, _) = run_stiff(
        &one(
            [0.0; 3],
            [6400.0, 6400.0, 6400.0],
            [1.0, 0.0, 0.0, 0.0],
            1.0,
        ),
        &stiff_cam(),
    );
    assert!(img.iter().all(|v| *v >= 0.0));
}

#[test]
fn stiff_tiny_and_huge_densities() {
    let (img, _) = run_stiff(
        &one([1.0, 2.0, 0.0], [3.0, 2.0, 4.0], [1.0, 0.0, 0.0, 0.0], 1e-8),
        &stiff_cam(),
    );
    assert!(
        img.iter().any(|v| *v > 0.0),
        "1e-8 density vanished (no absolute skip threshold)"
    );
    run_stiff(
        &one([1.0, 2.0, 0.0], [3.0, 2.0, 4.0], [1.0, 0.0, 0.0, 0.0], 1e6),
        &stiff_cam(),
    );
    // Extreme: density × extent near the f32 range (2.5e34 per pixel). The squared loss of
    // `run_stiff` would overflow f32 by itself, so use a linear loss here.
    let device = devices().remove(0).autodiff();
    let g = tensors(
        &one([0.0; 3], [6400.0; 3], [1.0, 0.0, 0.0, 0.0], 1e30),
        &device,
        true,
    );
    for opts in [ProjectOptions::default(), ProjectOptions::exact()] {
        let img = project(&g, &stiff_cam(), None, &opts).unwrap();
        assert!(to_vec(img.clone()).iter().all(|v| v.is_finite()));
        let grads = img.sum().backward();
        for t in [&g.means, &g.scales, &g.rotations, &g.densities] {
            assert!(
                to_vec(t.grad(&grads).unwrap())
                    .iter()
                    .all(|v| v.is_finite())
            );
        }
    }
}

#[test]
fn stiff_source_plane_and_off_detector() {
    // Source at 400·(cos 0.3, sin 0.3, 0): behind it, straddling it, and far off the detector.
    let (s, c) = 0.3f32.sin_cos();
    let behind = one(
        [500.0 * c, 500.0 * s, 0.0],
        [5.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        1.0,
    );
    let (img, _) = run_stiff(&behind, &stiff_cam());
    assert!(
        img.iter().all(|v| *v == 0.0),
        "a Gaussian behind the source must not project (affine)"
    );
    run_stiff(
        &one(
            [400.0 * c, 400.0 * s, 0.0],
            [5.0; 3],
            [1.0, 0.0, 0.0, 0.0],
            1.0,
        ),
        &stiff_cam(),
    );
    run_stiff(
        &one(
            [401.0 * c, 401.0 * s, 0.0],
            [5.0; 3],
            [1.0, 0.0, 0.0, 0.0],
            1.0,
        ),
        &stiff_cam(),
    );
    let (img, _) = run_stiff(
        &one([0.0, 0.0, 500.0], [2.0; 3], [1.0, 0.0, 0.0, 0.0], 1.0),
        &stiff_cam(),
    );
    assert!(img.iter().all(|v| *v == 0.0));
}

#[test]
fn stiff_empty_single_pixel_and_degenerate() {
    let empty = Params {
        means: vec![],
        scales: vec![],
        rotations: vec![],
        densities: vec![],
        channels: 1,
    };
    let (img, vol) = run_stiff(&empty, &stiff_cam());
    assert!(img.iter().chain(&vol).all(|v| *v == 0.0));
    // Single-pixel detector.
    let (img, _) = run_stiff(
        &one([0.0; 3], [3.0; 3], [1.0, 0.0, 0.0, 0.0], 1.0),
        &[cone(0.3, 1, 1, 3.0)],
    );
    assert_eq!(img.len(), 1);
    let want = (2.0 * std::f32::consts::PI).sqrt() * 3.0;
    assert!((img[0] - want).abs() < 1e-5 * want);
    // Degenerate: zero quaternion, zero and negative scales, NaN mean, NaN density → zero, no NaN.
    let mut p = Params::random(1, 1, 1.0, (1.0, 2.0), 3);
    let bad = [
        one([0.0; 3], [2.0; 3], [0.0; 4], 1.0),
        one([0.0; 3], [0.0, 2.0, 2.0], [1.0, 0.0, 0.0, 0.0], 1.0),
        one([0.0; 3], [-2.0, 2.0, 2.0], [1.0, 0.0, 0.0, 0.0], 1.0),
        one([f32::NAN, 0.0, 0.0], [2.0; 3], [1.0, 0.0, 0.0, 0.0], 1.0),
        one([0.0; 3], [2.0; 3], [1.0, 0.0, 0.0, 0.0], f32::NAN),
    ];
    let (clean_img, clean_vol) = run_stiff(&p, &stiff_cam());
    for b in bad {
        p.means.extend(&b.means);
        p.scales.extend(&b.scales);
        p.rotations.extend(&b.rotations);
        p.densities.extend(&b.densities);
    }
    let (img, vol) = run_stiff(&p, &stiff_cam());
    assert_eq!(
        img, clean_img,
        "degenerate Gaussians must contribute exactly zero"
    );
    assert_eq!(vol, clean_vol);
}

#[test]
fn stiff_exp_overflow_guards() {
    // Screen offsets and coordinates whose squared distance overflows f32: the exponent becomes
    // −∞ (contribution 0), never +∞ or NaN.
    let device = devices().remove(0).autodiff();
    let p = one([0.0; 3], [1e-3, 3.0, 3.0], [1.0, 0.0, 0.0, 0.0], 1.0);
    let g = tensors(&p, &device, true);
    let probe = Tensor::<3>::from_data(TensorData::new(vec![3e19f32, -3e19], [1, 1, 2]), &device)
        .require_grad();
    let img = project(&g, &stiff_cam(), Some(&probe), &ProjectOptions::default()).unwrap();
    assert!(to_vec(img.clone()).iter().all(|v| *v == 0.0));
    let grads = img.sum().backward();
    assert!(
        to_vec(g.means.grad(&grads).unwrap())
            .iter()
            .all(|v| v.is_finite())
    );
}
