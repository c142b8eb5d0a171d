use super::*;
use crate::device::cpu_device;
use crate::gaussians::host::HostGaussians;
use crate::gaussians::host::ScaleBounds;
use burn::tensor::TensorData;
use ndarray::Array3;
use prism_domain::physics::{Filtration, Material};

fn specs() -> Vec<ChannelSpec> {
    vec![
        ChannelSpec::Mono { kev: 40.0 },
        ChannelSpec::Polychromatic {
            kvp: 80,
            filtration: Filtration::Al2_5,
        },
        ChannelSpec::Window {
            lo_kev: 30.0,
            hi_kev: 60.0,
            kvp: 120,
            filtration: Filtration::Al2_5,
        },
        ChannelSpec::Mono { kev: 100.0 },
    ]
}

const WORLD: World = World {
    scale: 0.01,
    density_scale: 0.02,
};

/// Rendered basis images `[1, 3, 2, 2]` (normalised): air, soft tissue, bone, contrast.
fn rendered() -> Vec<f32> {
    // [b][pixel]
    let water = [0.0, 1.2, 0.8, 1.0];
    let bone = [0.0, 0.0, 0.9, 0.0];
    let iodine = [0.0, 0.0, 0.0, 0.3];
    [water, bone, iodine].concat()
}

/// The head's channel line integrals are the simulator's (`ChannelSpec::project` of the path
/// lengths the rendered columns stand for), for linear and beam-hardening channels alike.
#[test]
fn the_head_projects_as_the_simulator_synthesises() {
    let dev = cpu_device();
    let cfg = BasisConfig::default();
    let head = BasisHead::new(&cfg, "stage2", &specs(), &WORLD, &dev).unwrap();
    let r = rendered();
    let img = Tensor::<4>::from_data(TensorData::new(r.clone(), [1, 3, 2, 2]), &dev);
    let out = host_values(&head.project(img));
    assert_eq!(out.len(), 4 * 4);
    let k = WORLD.density_scale / WORLD.scale;
    let mats = cfg.materials.clone();
    for (c, spec) in specs().iter().enumerate() {
        for px in 0..4 {
            // L_b = R_b·k/μ̂_b (mm of pure material).
            let paths: Vec<_> = mats
                .iter()
                .enumerate()
                .map(|(b, &m)| {
                    let l = r[b * 4 + px] as f64 * k / head.reference_mu()[b];
                    (m, Array3::from_elem((1, 1, 1), l as f32))
                })
                .collect();
            let want = spec.project(&paths).unwrap()[[0, 0, 0]] as f64 / k;
            let got = out[c * 4 + px] as f64;
            assert!(
                (got - want).abs() <= 2e-5 * want.abs().max(1e-3),
                "channel {c} pixel {px}: head {got}, simulator {want}"
            );
        }
    }
}

/// The gradient through the log-sum-exp (with its detached shift) is the analytic one:
/// ∂p_c/∂R_b = Σ_n π_n·G_bn with π the nodes' transmitted-fluence shares (f64 central
/// differences of the host formula).
#[test]
fn the_head_gradient_matches_finite_differences() {
    let dev = cpu_device();
    let ad = dev.clone().autodiff();
    let cfg = BasisConfig::default();
    let head = BasisHead::new(&cfg, "stage2", &specs(), &WORLD, &ad).unwrap();
    let r = rendered();
    let x = Tensor::<4>::from_data(TensorData::new(r.clone(), [1, 3, 2, 2]), &ad).require_grad();
    // Loss: Σ_c (c+1)·Σ_px p_c(px), so every channel's gradient counts.
    let weights = Tensor::<4>::from_data(
        TensorData::new(vec![1f32, 2.0, 3.0, 4.0], [1, 4, 1, 1]),
        &ad,
    );
    let loss = (head.project(x.clone()) * weights).sum();
    let g = host_values(&x.grad(&loss.backward()).unwrap());

    let k = WORLD.density_scale / WORLD.scale;
    let nodes: Vec<Vec<(f64, Vec<f64>)>> = specs()
        .iter()
        .map(|s| s.nodes(&cfg.materials).unwrap())
        .collect();
    let host = |r: &[f64], px: usize| -> f64 {
        nodes
            .iter()
            .enumerate()
            .map(|(c, nodes)| {
                let s: f64 = nodes
                    .iter()
                    .map(|(w, mu)| {
                        let a: f64 = (0..3)
                            .map(|b| mu[b] * r[b * 4 + px] * k / head.reference_mu()[b])
                            .sum();
                        w * (-a).exp()
                    })
                    .sum();
                (c + 1) as f64 * -s.ln() / k
            })
            .sum()
    };
    let r64: Vec<f64> = r.iter().map(|&v| v as f64).collect();
    for i in 0..r.len() {
        let px = i % 4;
        let eps = 1e-4;
        let (mut p, mut m) = (r64.clone(), r64.clone());
        p[i] += eps;
        m[i] -= eps;
        let fd = (host(&p, px) - host(&m, px)) / (2.0 * eps);
        assert!(
            (g[i] as f64 - fd).abs() <= 1e-4 * fd.abs().max(1.0),
            "entry {i}: autodiff {}, finite difference {fd}",
            g[i]
        );
    }
}

/// Gaussians on a line, each with its raw basis columns (3 per Gaussian) from `raw`.
fn basis_model(raw: &[f32], dev: &Device) -> GaussianModel {
    let mut host = HostGaussians::empty(3);
    for (i, g) in raw.chunks(3).enumerate() {
        host.means.extend([i as f32 * 0.1, 0.0, 0.0]);
        host.scales.extend([0.0; 3]);
        host.rotations.extend([1.0, 0.0, 0.0, 0.0]);
        host.densities.extend_from_slice(g);
    }
    let bounds = ScaleBounds {
        min: 0.001,
        max: 0.5,
    };
    GaussianModel::new(&host, bounds, dev)
}

/// The start keeps stage 1's fit: the basis columns sum to the structural density, and the
/// channels' mean reference attenuation is that density too (every column's channel-mean
/// coefficient is 1).
#[test]
fn the_start_keeps_the_structural_density() {
    let dev = cpu_device();
    let cfg = BasisConfig::default();
    let head = BasisHead::new(&cfg, "stage2", &specs(), &WORLD, &dev).unwrap();
    let u = [-3.0f32, 0.0, 0.7, 4.0];
    let raw = head.initial_raw(&u);
    let model = basis_model(&raw, &dev);
    let ch = host_values(&head.channel_raw(&model));
    for (i, &u) in u.iter().enumerate() {
        let d = softplus(u as f64);
        let sum: f64 = raw[i * 3..i * 3 + 3]
            .iter()
            .map(|&r| softplus(r as f64))
            .sum();
        assert!(
            (sum - d).abs() < 1e-5 * d,
            "Gaussian {i}: columns sum to {sum}, not {d}"
        );
        assert!((softplus(raw[i * 3 + 1] as f64) - 0.05 * d).abs() < 1e-5 * d);
        let mean: f64 = ch[i * 4..i * 4 + 4]
            .iter()
            .map(|&r| softplus(r as f64))
            .sum::<f64>()
            / 4.0;
        assert!(
            (mean - d).abs() < 1e-4 * d,
            "Gaussian {i}: channel mean {mean}, not {d}"
        );
    }
}

/// An unseen channel is formed by the same physics as a trained one: at a trained channel's spec
/// `unseen_raw` is that channel's column of `channel_raw`, and at a monoenergetic 55 keV it is
/// `Σ_b v_b·μ_b(55 keV)/μ̂_b` from the attenuation table.
#[test]
fn an_unseen_channel_follows_the_materials_attenuation() {
    let dev = cpu_device();
    let cfg = BasisConfig::default();
    let head = BasisHead::new(&cfg, "stage2", &specs(), &WORLD, &dev).unwrap();
    let raw = [0.3f32, -1.0, 2.0, 1.5, -0.2, 0.1];
    let model = basis_model(&raw, &dev);
    let act = |r: f32| softplus(r as f64);
    let trained = host_values(&head.channel_raw(&model));
    for (c, spec) in specs().iter().enumerate() {
        let unseen = host_values(&head.unseen_raw(spec, &model).unwrap());
        for g in 0..2 {
            let (a, b) = (act(unseen[g]), act(trained[g * 4 + c]));
            assert!(
                (a - b).abs() < 1e-6 * b,
                "channel {c}, Gaussian {g}: {a} vs {b}"
            );
        }
    }
    let kev = ChannelSpec::Mono { kev: 55.0 };
    let unseen = host_values(&head.unseen_raw(&kev, &model).unwrap());
    let mats = head.basis().materials();
    for g in 0..2 {
        let want: f64 = (0..3)
            .map(|b| act(raw[g * 3 + b]) * mats[b].mu(55.0).unwrap() / head.reference_mu()[b])
            .sum();
        let got = act(unseen[g]);
        assert!(
            (got - want).abs() < 1e-5 * want,
            "Gaussian {g}: {got} vs {want}"
        );
    }
}

/// A basis the channels cannot separate, or a bad start, is refused naming the field.
#[test]
fn bad_bases_are_refused() {
    let dev = cpu_device();
    let two = [
        ChannelSpec::Mono { kev: 60.0 },
        ChannelSpec::Mono { kev: 80.0 },
    ];
    let e = BasisHead::new(&BasisConfig::default(), "stage2", &two, &WORLD, &dev)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("stage2.basis") && e.contains("at least 3 channels"),
        "{e}"
    );
    let cfg = BasisConfig {
        init_share: 0.5,
        ..BasisConfig::default()
    };
    let e = cfg.validate("stage2").unwrap_err().to_string();
    assert!(e.contains("stage2.basis.init_share"), "{e}");
    let cfg = BasisConfig {
        materials: vec![Material::Water, Material::Water],
        ..BasisConfig::default()
    };
    let e = cfg.validate("stage2").unwrap_err().to_string();
    assert!(e.contains("stage2.basis") && e.contains("twice"), "{e}");
}
