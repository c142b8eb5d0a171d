//! End-to-end checks of the Gaussian trainers on a tiny two-channel scene (24³ grid, 40²
//! detector, 24 training views; one channel missing at every third view).

use super::config::{GaussianConfig, GaussianMethod};
use super::densify::{DensifyConfig, densify_and_prune};
use super::host::{HostGaussians, ScaleBounds, inverse_softplus};
use super::init::{InitConfig, from_fdk};
use super::io::{load_model, save_model, write_ply};
use super::model::GaussianModel;
use super::world::World;
use super::*;
use crate::classic::recon::tests::scene;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn tiny(method: GaussianMethod) -> GaussianConfig {
    let mut c = GaussianConfig::new(method);
    c.iterations = 40;
    c.density_iterations = 20;
    c.init.n_points = 500;
    c.eval_every = 20;
    c.densify = Some(DensifyConfig {
        from: 10,
        until: 30,
        every: 20,
        grad_threshold: 1e-5,
        ..DensifyConfig::default()
    });
    c
}

fn losses(dir: &std::path::Path) -> Vec<(String, usize, f64, usize)> {
    std::fs::read_to_string(dir.join(log::LOG_FILE))
        .unwrap()
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (
                v["stage"].as_str().unwrap().to_string(),
                v["iter"].as_u64().unwrap() as usize,
                v["loss"]["total"].as_f64().unwrap(),
                v["n_gaussians"].as_u64().unwrap() as usize,
            )
        })
        .collect()
}

#[test]
fn both_methods_train_densify_score_and_repeat_exactly() {
    let scene = scene();
    let dev = test_device();
    for method in [GaussianMethod::R2gs, GaussianMethod::Stage1] {
        let cfg = tiny(method);
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        let report = run::run(&cfg, &scene, a.path(), &dev).unwrap().unwrap();
        run::run(&cfg, &scene, b.path(), &dev).unwrap();
        let la = losses(a.path());
        assert_eq!(la, losses(b.path()), "{method:?}: same seed, same log");
        // Records at iterations 20 and 40 of every geometry stage (one per channel for r2gs),
        // and at 20 of stage 1's density stage.
        let records = match method {
            GaussianMethod::R2gs => 4,
            GaussianMethod::Stage1 => 3,
        };
        assert_eq!(la.len(), records, "{la:?}");
        let first = &la[0];
        let second = &la[1];
        assert!(second.2 < first.2, "{method:?}: loss falls: {la:?}");
        assert!(
            first.3 != 500 || second.3 != 500,
            "densification ran: {la:?}"
        );
        let train: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(a.path().join(run::TRAIN_FILE)).unwrap())
                .unwrap();
        let d = &train["stages"][0]["densify"];
        assert!(
            d["cloned"].as_u64().unwrap() + d["split"].as_u64().unwrap() > 0,
            "{train}"
        );
        for ch in &report.channels {
            assert!(ch.psnr.is_finite() && ch.psnr > 15.0, "{method:?}: {ch:?}");
            assert!(a.path().join(format!("{}.npy", ch.label)).exists());
        }
    }
}

#[test]
fn adam_state_follows_clone_split_and_prune() {
    let dev = test_device();
    let b = ScaleBounds {
        min: 0.001,
        max: 1.0,
    };
    let mut g = HostGaussians::empty(2);
    for i in 0..6 {
        g.means.extend_from_slice(&[0.1 * i as f32, 0.0, 0.0]);
        let s = b.raw(if i % 2 == 0 { 0.05 } else { 0.4 }) as f32;
        g.scales.extend_from_slice(&[s, s, s]);
        g.rotations.extend_from_slice(&[1.0, 0.0, 0.0, 0.0]);
        let d = if i == 5 { 1e-8 } else { 0.5 };
        g.densities
            .extend_from_slice(&[inverse_softplus(d) as f32, inverse_softplus(d) as f32]);
    }
    let mut model = GaussianModel::new(&g, b, &dev);
    // One Adam step so that moments are non-zero.
    let act = model.activate(Some(Learnable::ALL));
    let loss = act.gaussians.densities.clone().sum() + act.gaussians.means.clone().sum();
    let grads = loss.backward();
    let gm = act.leaves[0].grad(&grads).unwrap();
    model.means.step(gm, 1e-3);
    let scores = [1.0f32, 1.0, 0.0, 0.0, 0.0, 1.0];
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (next, src, counts) = densify_and_prune(
        &model.to_host(),
        &scores,
        &b,
        ([-1.0; 3], [1.0; 3]),
        &DensifyConfig::default(),
        &mut rng,
    );
    // Row 0 cloned, rows 1 and 5 split (5 then pruned with its faint children), 2–4 kept.
    assert_eq!((counts.cloned, counts.split), (1, 2));
    model.remap(&next, &src);
    let k = next.len();
    assert_eq!(k, 4 + 1 + 2);
    assert_eq!(model.means.shapes(), [[k, 3]; 3]);
    assert_eq!(model.scales.shapes(), [[k, 3]; 3]);
    assert_eq!(model.rotations.shapes(), [[k, 4]; 3]);
    assert_eq!(model.densities.shapes(), [[k, 2]; 3]);
    // Stepping again works on the new shapes.
    let act = model.activate(Some(Learnable::ALL));
    let grads = act.gaussians.means.clone().sum().backward();
    model.means.step(act.leaves[0].grad(&grads).unwrap(), 1e-3);
    assert_eq!(model.len(), k);
}

#[test]
fn initial_scales_are_the_lattice_spacing_and_models_round_trip() {
    let scene = scene();
    let dev = test_device();
    let g = &scene.geometry;
    // A constant FDK volume: every voxel is a candidate; with all of them drawn, each Gaussian's
    // three nearest neighbours sit one voxel away, so every scale is one (normalised) voxel.
    let fdk = ndarray::Array3::<f32>::from_elem(g.volume.shape_zyx(), 0.02);
    let world = World::new(g, 0.02).unwrap();
    let bounds = ScaleBounds {
        min: 0.001,
        max: 1.0,
    };
    let cfg = InitConfig {
        n_points: g.volume.len(),
        ..InitConfig::default()
    };
    let host = from_fdk(fdk.view(), &g.volume, &world, &bounds, &cfg, 0, &dev).unwrap();
    assert_eq!(host.len(), g.volume.len());
    let voxel = g.volume.dx * world.scale;
    for r in host.scales.iter().step_by(97) {
        let s = bounds.activate(*r as f64);
        assert!((s - voxel).abs() < 1e-5 * voxel.max(1.0), "{s} vs {voxel}");
    }
    // Densities: softplus(raw) = 0.15 · (0.02 / 0.02).
    let d = host::softplus(host.densities[0] as f64);
    assert!((d - 0.15).abs() < 1e-6, "{d}");

    let model = GaussianModel::new(&host, bounds, &dev);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("g.safetensors");
    save_model(&path, &model, &world, &["a".into()]).unwrap();
    let back = load_model(&path, &dev).unwrap();
    assert_eq!(back.model.to_host(), host);
    assert_eq!(back.world, world);
    assert_eq!(back.channels, vec!["a".to_string()]);
    let ply = dir.path().join("g.ply");
    write_ply(&ply, &model, &world, &["a".into()]).unwrap();
    let bytes = std::fs::read(&ply).unwrap();
    let text = String::from_utf8_lossy(&bytes[..400]);
    assert!(
        text.contains(&format!("element vertex {}", host.len())),
        "{text}"
    );
    let header_end = text.find("end_header\n").unwrap() + "end_header\n".len();
    assert_eq!(bytes.len() - header_end, host.len() * 11 * 4);
    // A corrupted file names the file and the problem.
    std::fs::write(&path, b"nonsense").unwrap();
    let e = load_model(&path, &dev).err().unwrap().to_string();
    assert!(e.contains("g.safetensors"), "{e}");
}
