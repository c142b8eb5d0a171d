//! End-to-end checks of the Gaussian trainers on a tiny two-channel scene (24³ grid, 40²
//! detector, 24 training views; one channel missing at every third view).

use super::tests::scene;
use super::{RunDir, RunOptions, run};
use crate::device::cpu_device;
use crate::evaluate::{Evaluation, Metrics};
use crate::gaussians::config::{DataNorm, DataWeighting, DensifyConfig, InitConfig, TvGuide};
use crate::gaussians::host::{self, HostGaussians, ScaleBounds, inverse_softplus};
use crate::gaussians::io::{ModelInfo, load_model, save_model, write_ply};
use crate::gaussians::train::densify::densify_and_prune;
use crate::gaussians::{GaussianModel, GeometryConfig, Learnable, ProjectionConfig, World};
use crate::init::from_fdk;
use crate::methods::fourdsg::stage2::config::ResidualConfig;
use crate::methods::fourdsg::{FourDsgConfig, FourDsgMethod, query};
use crate::methods::r2gs::R2gsConfig;
use crate::{Method, MethodConfig, Result};
use burn::tensor::Device;
use prism_domain::observe::Silent;
use prism_domain::scene::Scene;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// Run `cfg` on `scene` into `out` on `device`, continuing from the stage-1 checkpoint `from`;
/// the scores.
fn run_from<C: Clone + Into<MethodConfig>>(
    cfg: &C,
    scene: &Scene,
    out: &Path,
    device: &Device,
    from: Option<&Path>,
) -> Result<Metrics> {
    let options = RunOptions {
        device: device.clone(),
        from_geometry: from,
        observer: &Silent,
        evaluation: &Evaluation::default(),
        checkpoint: None,
    };
    let config: MethodConfig = cfg.clone().into();
    let outcome = run(&config, scene, RunDir::create(out, false)?, &options)?;
    Ok(outcome.metrics.expect("the test scenes have references"))
}

fn run_on<C: Clone + Into<MethodConfig>>(
    cfg: &C,
    scene: &Scene,
    out: &Path,
    device: &Device,
) -> Result<Metrics> {
    run_from(cfg, scene, out, device, None)
}

/// The geometry stage of the tiny runs: 40 iterations from 500 Gaussians, densifying at 20.
pub(crate) fn tiny_geometry() -> GeometryConfig {
    GeometryConfig {
        iterations: 40,
        init: InitConfig {
            n_points: 500,
            ..InitConfig::default()
        },
        eval_every: 20,
        densify: Some(DensifyConfig {
            from: 10,
            until: 30,
            every: 20,
            grad_threshold: 1e-5,
            ..DensifyConfig::default()
        }),
        ..GeometryConfig::default()
    }
}

/// A tiny 4D-SG run (stage-1 densities: 20 iterations).
pub(crate) fn tiny(method: FourDsgMethod) -> FourDsgConfig {
    let mut c = FourDsgConfig::new(method);
    c.geometry = tiny_geometry();
    c.spectral.density_iterations = 20;
    c
}

/// A tiny 4D-SG run without densification: `geometry` stage-1 and `spectral` stage-2
/// iterations, a one-block curve model of width 8.
pub(crate) fn tiny_spectral(geometry: usize, spectral: usize) -> FourDsgConfig {
    let mut c = tiny(FourDsgMethod::Full);
    c.geometry.iterations = geometry;
    c.geometry.densify = None;
    c.spectral.stage2.iterations = spectral;
    c.spectral.stage2.curve_model.width = 8;
    c.spectral.stage2.curve_model.depth = 1;
    c
}

pub(crate) fn tiny_r2gs() -> R2gsConfig {
    R2gsConfig {
        geometry: tiny_geometry(),
    }
}

pub(super) fn losses(dir: &std::path::Path) -> Vec<(String, usize, f64, usize)> {
    std::fs::read_to_string(dir.join(RunDir::LOG))
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

/// `loss.weighting: counts` and `loss.data: rms` each reach every stage of 4D-SG (an
/// interleaved scene: the weights follow each view's measured channels): the logged losses
/// differ from the plain run's from the first record on, and the run scores.
#[test]
fn data_term_options_reach_both_stages_of_4dsg() {
    let scene = scene();
    let dev = cpu_device();
    let mut plain = tiny(FourDsgMethod::Full);
    // Stage 2's first logged loss is all the check needs (its default 1 000 iterations cost
    // minutes here).
    plain.spectral.stage2.iterations = 20;
    let mut weighted = plain.clone();
    weighted.geometry.loss.weighting = DataWeighting::Counts;
    let mut squares = plain.clone();
    squares.geometry.loss.data = DataNorm::Rms;
    let a = tempfile::tempdir().unwrap();
    run_on(&plain, &scene, a.path(), &dev).unwrap();
    let la = losses(a.path());
    let stages = |l: &[(String, usize, f64, usize)]| {
        let mut s: Vec<String> = l.iter().map(|r| r.0.clone()).collect();
        s.dedup();
        s
    };
    assert!(stages(&la).len() >= 2, "{:?}", stages(&la));
    for (option, config) in [("counts", weighted), ("rms", squares)] {
        let b = tempfile::tempdir().unwrap();
        let m = run_on(&config, &scene, b.path(), &dev).unwrap();
        let lb = losses(b.path());
        assert_eq!(stages(&la), stages(&lb), "{option}");
        for stage in stages(&la) {
            let first = |l: &[(String, usize, f64, usize)]| {
                l.iter().find(|r| r.0 == stage).map(|r| r.2).unwrap()
            };
            assert_ne!(
                first(&la),
                first(&lb),
                "{option}, stage {stage}: the option changed nothing"
            );
        }
        assert!(
            m.channels
                .iter()
                .all(|c| c.scores.psnr.is_finite() && c.scores.psnr > 15.0),
            "{option}: {:?}",
            m.channels
        );
    }
}

/// `loss.tv_channel_weight` weighs one channel's TV: R²-Gaussian with λ_TV = 0.05 and channel
/// 1's weight 2 trains channel 1 exactly as λ_TV = 0.1 does (TV is positively homogeneous and
/// ×2 is exact in floating point), and channel 0 as λ_TV = 0.05 does, not as 0.1.
#[test]
fn a_channel_tv_weight_is_that_channels_lambda_tv_scaled() {
    let scene = scene();
    let dev = cpu_device();
    let mut weighted = tiny_r2gs();
    weighted.geometry.iterations = 20;
    weighted.geometry.loss.lambda_tv = 0.05;
    let mut doubled = weighted.clone();
    doubled.geometry.loss.lambda_tv = 0.1;
    weighted
        .geometry
        .loss
        .tv_channel_weight
        .insert(scene.channels[1].label.clone(), 2.0);
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    run_on(&weighted, &scene, a.path(), &dev).unwrap();
    run_on(&doubled, &scene, b.path(), &dev).unwrap();
    let volume = |dir: &Path, c: usize| -> ndarray::Array3<f32> {
        ndarray_npy::read_npy(dir.join(RunDir::volume_file(&scene.channels[c].label))).unwrap()
    };
    assert_ne!(
        volume(a.path(), 0),
        volume(b.path(), 0),
        "channel 0 keeps λ_TV = 0.05"
    );
    assert_eq!(
        volume(a.path(), 1),
        volume(b.path(), 1),
        "channel 1 trains as with λ_TV = 0.1"
    );
}

#[test]
fn both_methods_train_densify_score_and_repeat_exactly() {
    let scene = scene();
    let dev = cpu_device();
    for method in [Method::R2gs, Method::FourDsgStage1] {
        let cfg: MethodConfig = match method {
            Method::R2gs => tiny_r2gs().into(),
            _ => tiny(FourDsgMethod::Stage1).into(),
        };
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        let report = run_on(&cfg, &scene, a.path(), &dev).unwrap();
        run_on(&cfg, &scene, b.path(), &dev).unwrap();
        let la = losses(a.path());
        assert_eq!(la, losses(b.path()), "{method:?}: same seed, same log");
        // Records at iterations 20 and 40 of every geometry stage (one per channel for r2gs),
        // and at 20 of stage 1's density stage.
        let records = match method {
            Method::R2gs => 4,
            _ => 3,
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
            serde_json::from_str(&std::fs::read_to_string(a.path().join(RunDir::TRAIN)).unwrap())
                .unwrap();
        let d = &train["stages"][0]["densify"];
        assert!(
            d["cloned"].as_u64().unwrap() + d["split"].as_u64().unwrap() > 0,
            "{train}"
        );
        // Test views are rendered by the model itself.
        assert!(
            report
                .protocol
                .projections
                .contains("Gaussian renderer (affine"),
            "{:?}",
            report.protocol
        );
        for ch in &report.channels {
            assert!(
                ch.scores.psnr.is_finite() && ch.scores.psnr > 15.0,
                "{method:?}: {ch:?}"
            );
            assert!(ch.proj_psnr.unwrap() > 15.0, "{method:?}: {ch:?}");
            assert!(a.path().join(format!("{}.npy", ch.label)).exists());
        }
    }
}

#[test]
fn adam_state_follows_clone_split_and_prune() {
    let dev = cpu_device();
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
    let dev = cpu_device();
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
    let info = ModelInfo {
        channels: vec!["a".into()],
        tau: vec![0.0],
        coordinates: vec![70.0],
        unit: "keV".into(),
        coordinate_range: [70.0, 70.0],
        geometry: g.clone(),
        projection: ProjectionConfig {
            mode: prism_render::ProjectionMode::Exact,
            cutoff: 2.5,
        },
        monoenergetic: true,
        basis: false,
    };
    save_model(&path, &model, None, &world, &info).unwrap();
    // Same model, same bytes (safetensors alone writes its metadata in hash-map order).
    let again = dir.path().join("again.safetensors");
    save_model(&again, &model, None, &world, &info).unwrap();
    assert!(std::fs::read(&path).unwrap() == std::fs::read(&again).unwrap());
    let back = load_model(&path, &dev).unwrap();
    assert_eq!(back.model.to_host(), host);
    assert_eq!(back.world, world);
    assert_eq!(back.info, info);
    let ply = dir.path().join("g.ply");
    write_ply(&ply, &model, None, &world, &info.channels).unwrap();
    let bytes = std::fs::read(&ply).unwrap();
    let text = String::from_utf8_lossy(&bytes[..400]);
    assert!(
        text.contains(&format!("element vertex {}", host.len())),
        "{text}"
    );
    let header_end = text.find("end_header\n").unwrap() + "end_header\n".len();
    assert_eq!(bytes.len() - header_end, host.len() * 11 * 4);
    // A stored negative density scale (every μ would be negative) is refused on load.
    let negative = World {
        density_scale: -world.density_scale,
        ..world
    };
    let bad = dir.path().join("negative.safetensors");
    save_model(&bad, &model, None, &negative, &info).unwrap();
    let e = load_model(&bad, &dev).err().unwrap().to_string();
    assert!(
        e.contains("negative.safetensors") && e.contains("metadata.density_scale"),
        "{e}"
    );
    // Forged files: each is refused with the file's name, before any tensor is built from it.
    let good = std::fs::read(&again).unwrap();
    let header_len = u64::from_le_bytes(good[..8].try_into().unwrap()) as usize;
    let header = String::from_utf8(good[8..8 + header_len].to_vec()).unwrap();
    let with_header = |h: &str| {
        let mut h = h.to_string();
        while !h.len().is_multiple_of(8) {
            h.push(' ');
        }
        let mut b = (h.len() as u64).to_le_bytes().to_vec();
        b.extend_from_slice(h.as_bytes());
        b.extend_from_slice(&good[8 + header_len..]);
        b
    };
    let k = host.len();
    let mut huge_len = good.clone();
    huge_len[..8].copy_from_slice(&(1u64 << 62).to_le_bytes());
    let forged: [(&str, Vec<u8>); 6] = [
        ("nonsense", b"nonsense".to_vec()),
        ("a header length of 2^62 bytes", huge_len),
        ("the data cut short", good[..good.len() - 12].to_vec()),
        (
            "means claiming more rows than the data holds",
            with_header(&header.replacen(&format!("[{k},3]"), &format!("[{},3]", k * 1000), 1)),
        ),
        (
            "one tensor with fewer Gaussians than the others",
            with_header(&header.replacen(&format!("[{k},4]"), &format!("[{},4]", k - 1), 1)),
        ),
        (
            "more channels in the metadata than density columns",
            with_header(
                &header.replace(r#"\"channels\":[\"a\"]"#, r#"\"channels\":[\"a\",\"b\"]"#),
            ),
        ),
    ];
    for (what, bytes) in forged {
        assert_ne!(bytes, good, "{what}: the forgery changed nothing");
        std::fs::write(&path, &bytes).unwrap();
        let e = load_model(&path, &dev).err().map(|e| e.to_string());
        let e = e.unwrap_or_else(|| panic!("{what}: loaded"));
        assert!(e.contains("g.safetensors"), "{what}: {e}");
    }
}

#[test]
fn four_dsg_trains_the_curve_model_and_predicts_a_held_out_channel() {
    // Three channels (40, 55, 70 keV analogues) so the middle one can be held out.
    let scene = three_channel_scene();
    let dev = cpu_device();
    for kind in [
        prism_gscnet::CurveModelKind::Gscnet,
        prism_gscnet::CurveModelKind::Mlp,
    ] {
        let mut cfg = tiny(FourDsgMethod::Full);
        cfg.geometry.iterations = 20;
        cfg.geometry.densify = None;
        cfg.spectral.stage2.iterations = 20;
        cfg.spectral.stage2.curve_model.kind = kind;
        cfg.spectral.stage2.curve_model.width = 8;
        cfg.spectral.stage2.curve_model.depth = 1;
        cfg.spectral.holdout_channels = vec![scene.channels[1].label.clone()];
        let dir = tempfile::tempdir().unwrap();
        let report = run_on(&cfg, &scene, dir.path(), &dev).unwrap();
        assert_eq!(
            report.channels.len(),
            2,
            "metrics.json holds the observed channels"
        );
        let log = losses(dir.path());
        let s2: Vec<_> = log.iter().filter(|r| r.0 == kind.name()).collect();
        assert_eq!(s2.len(), 1, "{log:?}");
        let holdout: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(RunDir::HOLDOUT)).unwrap(),
        )
        .unwrap();
        let h = &holdout[0];
        assert_eq!(h["label"], scene.channels[1].label.as_str());
        assert!(h["volume"]["psnr"].as_f64().unwrap() > 15.0, "{holdout}");
        assert!(h["proj_psnr"].as_f64().unwrap() > 15.0, "{holdout}");
        // Queries: at an observed grid point the query reproduces the fitted channel's volume;
        // outside the grid it is refused unless extrapolation is asked for.
        let q = query::Query::open(&RunDir::spectral_model(dir.path()).unwrap(), &dev).unwrap();
        let tau0 = q.loaded.info.tau[0];
        let v = q.volume(query::QueryAt::Tau(tau0), false).unwrap();
        let fitted: ndarray::Array3<f32> =
            ndarray_npy::read_npy(dir.path().join(format!("{}.npy", scene.channels[0].label)))
                .unwrap();
        let diff = (&v - &fitted).mapv(f32::abs).fold(0.0f32, |a, &b| a.max(b));
        let peak = fitted.fold(0.0f32, |a, &b| a.max(b));
        assert!(diff <= 1e-5 * peak, "{diff} vs peak {peak}");
        let e = q
            .volume(query::QueryAt::Tau(1.5), false)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("tau") && e.contains("extrapolate"), "{e}");
        assert!(q.volume(query::QueryAt::Tau(1.5), true).is_ok());
        let p = q
            .projections(query::QueryAt::Coordinate(55.0), false)
            .unwrap();
        assert_eq!(p.dim(), (scene.n_views(), 40, 40));
        assert!(p.iter().all(|x| x.is_finite()));
    }
}

#[test]
fn a_basis_run_predicts_a_held_out_channel_by_the_physics() {
    // Water and bone from 40 and 70 keV; 55 keV is formed from the materials' attenuation at
    // 55 keV (not interpolated), and holdout.json says so.
    use crate::methods::fourdsg::stage2::config::BasisConfig;
    use prism_domain::physics::Material;
    let scene = three_channel_scene();
    let dev = cpu_device();
    let mut cfg = tiny(FourDsgMethod::Full);
    cfg.geometry.iterations = 20;
    cfg.geometry.densify = None;
    cfg.spectral.stage2.iterations = 20;
    cfg.spectral.stage2.basis = Some(BasisConfig {
        materials: vec![Material::Water, Material::CorticalBone],
        init_share: 0.05,
    });
    cfg.spectral.holdout_channels = vec![scene.channels[1].label.clone()];
    let dir = tempfile::tempdir().unwrap();
    run_on(&cfg, &scene, dir.path(), &dev).unwrap();
    let holdout: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join(RunDir::HOLDOUT)).unwrap())
            .unwrap();
    let h = &holdout[0];
    assert_eq!(h["predictor"], "physics", "{holdout}");
    assert!(h["volume"]["psnr"].as_f64().unwrap() > 15.0, "{holdout}");
}

#[test]
fn bad_holdouts_and_single_channel_scenes_are_handled() {
    let scene = three_channel_scene();
    let mut cfg = tiny(FourDsgMethod::Full);
    cfg.spectral.holdout_channels = vec![scene.channels[0].label.clone()];
    let e = cfg.holdout_indices(&scene).unwrap_err().to_string();
    assert!(
        e.contains("holdout_channels[0]") && e.contains("extrapolation"),
        "{e}"
    );
    cfg.spectral.holdout_channels = vec!["nope".into()];
    let e = cfg.holdout_indices(&scene).unwrap_err().to_string();
    assert!(e.contains("nope"), "{e}");
    // R²-Gaussian cannot predict an unobserved channel: it has no such setting.
    let e = MethodConfig::from_yaml("method: r2gs\nholdout_channels: [b]\n", Path::new("r.yaml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("r.yaml") && e.contains("holdout_channels") && e.contains("`r2gs`"),
        "{e}"
    );
}

/// The tiny scene with a third channel at 55 keV between 40 and 70 keV, every view complete.
pub(super) fn three_channel_scene() -> prism_domain::scene::Scene {
    use prism_domain::physics::ChannelSpec;
    use prism_domain::scene::{Channel, SpectralCoordinate, normalise_tau};
    let mut s = scene();
    s.availability.fill(true);
    let ph = prism_domain::phantom::SpectralPhantom::builtin(22.0).unwrap();
    let paths = ph.material_paths(&s.geometry).unwrap();
    let fractions = ph.fractions(&s.geometry.volume, 3).unwrap();
    let kevs = [40.0, 55.0, 70.0];
    let proj: Vec<_> = kevs
        .iter()
        .map(|&kev| ChannelSpec::Mono { kev }.project(&paths).unwrap())
        .collect();
    let refs: Vec<_> = kevs
        .iter()
        .map(|&kev| ChannelSpec::Mono { kev }.volume(&fractions).unwrap())
        .collect();
    let views = s.n_views();
    s.projections = ndarray::stack(
        ndarray::Axis(0),
        &proj.iter().map(|p| p.view()).collect::<Vec<_>>(),
    )
    .unwrap();
    s.references = Some(
        ndarray::stack(
            ndarray::Axis(0),
            &refs.iter().map(|p| p.view()).collect::<Vec<_>>(),
        )
        .unwrap(),
    );
    s.availability = ndarray::Array2::from_elem((views, 3), true);
    s.channels = kevs
        .iter()
        .map(|&kev| Channel::new(format!("{kev}keV"), SpectralCoordinate::Energy { kev }))
        .collect();
    normalise_tau(&mut s.channels).unwrap();
    s.validate().unwrap();
    s
}

/// The whole 4D-SG pipeline (stage 1, GSC-Net stage 2 with its fused scan/conv ops, holdout
/// scoring) on the deprecated NdArray backend too: the custom ops are registered for both CPU
/// backends, so this is the same code path as on Flex.
#[cfg(feature = "ndarray")]
#[test]
fn stage_two_runs_on_the_ndarray_backend() {
    let scene = three_channel_scene();
    let cfg = tiny_spectral(8, 6);
    let dir = tempfile::tempdir().unwrap();
    #[allow(deprecated)] // burn-ndarray goes in Burn 0.23; until then our ops serve it too
    let dev = burn::tensor::Device::ndarray();
    let report = run_on(&cfg, &scene, dir.path(), &dev).unwrap();
    assert!(report.channels.iter().all(|c| c.scores.psnr.is_finite()));
    let log = losses(dir.path());
    assert!(log.iter().any(|r| r.0 == "gscnet"), "{log:?}");
    assert!(log.iter().all(|r| r.2.is_finite()), "{log:?}");
}

/// A 4D-SG run continued from its own stage-1 checkpoint gives the uninterrupted run's log and
/// volumes bit for bit (the checkpoint carries the Adam moments the spectral stage continues,
/// after densification moved them); a checkpoint from other stage-1 settings or another scene
/// is refused before anything is written, while spectral-stage settings may differ.
#[test]
fn a_4dsg_run_continues_from_its_stage1_checkpoint_exactly() {
    let scene = three_channel_scene();
    let dev = cpu_device();
    let mut cfg = tiny(FourDsgMethod::Full);
    cfg.geometry.iterations = 30;
    cfg.spectral.stage2.iterations = 10;
    cfg.spectral.stage2.curve_model.width = 8;
    cfg.spectral.stage2.curve_model.depth = 1;
    let a = tempfile::tempdir().unwrap();
    run_on(&cfg, &scene, a.path(), &dev).unwrap();
    let ckpt = a.path().join(RunDir::GEOMETRY);
    assert!(ckpt.is_file());

    let b = tempfile::tempdir().unwrap();
    run_from(&cfg, &scene, b.path(), &dev, Some(a.path())).unwrap();
    assert_eq!(losses(a.path()), losses(b.path()));
    assert!(losses(b.path()).iter().any(|r| r.0 == "geometry"));
    for ch in &scene.channels {
        let file = format!("{}.npy", ch.label);
        assert!(
            std::fs::read(a.path().join(&file)).unwrap()
                == std::fs::read(b.path().join(&file)).unwrap(),
            "{file} differs"
        );
    }
    let stages = |d: &std::path::Path| -> serde_json::Value {
        let t: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join(RunDir::TRAIN)).unwrap()).unwrap();
        t["stages"].clone()
    };
    assert_eq!(
        stages(a.path())[0],
        stages(b.path())[0],
        "stage-1 summary carried over"
    );
    assert_eq!(stages(b.path()).as_array().unwrap().len(), 2);

    // Spectral-stage settings may change (the loss's channel settings among them: stage 1 fits
    // one common density); stage-1 settings and the scene may not.
    let mut other_stage2 = cfg.clone();
    other_stage2.spectral.stage2.iterations = 2;
    other_stage2.geometry.loss.tv_guide = Some(TvGuide { eta: 0.1 });
    other_stage2
        .geometry
        .loss
        .tv_channel_weight
        .insert(scene.channels[2].label.clone(), 3.0);
    other_stage2.spectral.stage2.residual = Some(ResidualConfig { weight: 0.1 });
    let c = tempfile::tempdir().unwrap();
    run_from(&other_stage2, &scene, c.path(), &dev, Some(&ckpt)).unwrap();
    let mut other_init = cfg.clone();
    other_init.geometry.init.n_points = 400;
    let d = tempfile::tempdir().unwrap();
    let refused = d.path().join("refused");
    let e = run_from(&other_init, &scene, &refused, &dev, Some(a.path()))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains(RunDir::GEOMETRY) && e.contains("`init`") && e.contains("400"),
        "{e}"
    );
    assert!(
        !refused.exists(),
        "a refused checkpoint leaves no run directory"
    );
    let mut other_scene = scene.clone();
    other_scene.projections[[0, 0, 20, 20]] += 0.01;
    let e = run_from(&cfg, &other_scene, &refused, &dev, Some(a.path()))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("scene"), "{e}");
    // A trained model is not a checkpoint.
    let model_file = a.path().join("gaussians.safetensors");
    let e = run_from(&cfg, &scene, &refused, &dev, Some(&model_file))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("gaussians.safetensors") && e.contains("prism-geometry/1"),
        "{e}"
    );
    let e = run_from(&tiny_r2gs(), &scene, &refused, &dev, Some(a.path()))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("r2gs"), "{e}");
}

/// Channel residuals start at zero: the first spectral step with them moves the geometry
/// (positions, scales, rotations) exactly as the step without them, since at r = 0 the curve, the
/// loss and its gradients are the same; the residuals themselves take a step, so the channels'
/// saved raw densities differ.
#[test]
fn zero_channel_residuals_leave_the_first_spectral_step_as_it_is() {
    let scene = three_channel_scene();
    let dev = cpu_device();
    let cfg = tiny_spectral(10, 1);
    let mut with = cfg.clone();
    with.spectral.stage2.residual = Some(ResidualConfig { weight: 0.1 });
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    run_on(&cfg, &scene, a.path(), &dev).unwrap();
    run_on(&with, &scene, b.path(), &dev).unwrap();
    let load = |d: &Path| {
        load_model(&RunDir::spectral_model(d).unwrap(), &dev)
            .unwrap()
            .model
    };
    let (ma, mb) = (load(a.path()), load(b.path()));
    let host = |t: &burn::tensor::Tensor<2>| crate::device::host_values(t);
    for (what, x, y) in [
        ("means", &ma.means, &mb.means),
        ("scales", &ma.scales, &mb.scales),
        ("rotations", &ma.rotations, &mb.rotations),
    ] {
        assert!(host(&x.value) == host(&y.value), "{what} differ");
    }
    let (da, db) = (host(&ma.densities.value), host(&mb.densities.value));
    assert_eq!(da.len(), db.len());
    let moved = da.iter().zip(&db).filter(|(x, y)| x != y).count();
    assert!(
        moved > da.len() / 2,
        "{moved} of {} raw densities moved",
        da.len()
    );
}

#[test]
fn the_projection_mode_reaches_training_and_queries() {
    use crate::gaussians::volume::render_views;
    use crate::methods::fourdsg::query::{Query, QueryAt};
    use prism_render::ProjectionMode;
    let scene = scene();
    let dev = cpu_device();
    let mut cfg = tiny(FourDsgMethod::Stage1);
    cfg.geometry.iterations = 30;
    cfg.spectral.density_iterations = 10;
    let affine_dir = tempfile::tempdir().unwrap();
    run_on(&cfg, &scene, affine_dir.path(), &dev).unwrap();
    cfg.geometry.projection = ProjectionConfig {
        mode: ProjectionMode::Exact,
        cutoff: 3.0,
    };
    let dir = tempfile::tempdir().unwrap();
    let report = run_on(&cfg, &scene, dir.path(), &dev).unwrap();
    assert!(
        report.channels.iter().all(|c| c.scores.psnr > 15.0),
        "{report:?}"
    );
    let resolved = std::fs::read_to_string(dir.path().join("config.resolved.yaml")).unwrap();
    assert!(resolved.contains("mode: exact"), "{resolved}");
    // Same seed and settings but the projection: the losses differ from the first record on.
    let (la, le) = (losses(affine_dir.path()), losses(dir.path()));
    assert_eq!(la.len(), le.len());
    assert!(la.iter().zip(&le).all(|(a, e)| a.2 != e.2), "{la:?} {le:?}");

    // The model file keeps the mode, and queries render with it.
    let q = Query::open(&RunDir::spectral_model(dir.path()).unwrap(), &dev).unwrap();
    assert_eq!(q.loaded.info.projection, cfg.geometry.projection);
    let queried = q.projections(QueryAt::Tau(0.0), false).unwrap();
    let l = &q.loaded;
    let views: Vec<usize> = (0..l.info.geometry.views()).collect();
    let render = |options: &prism_render::ProjectOptions| {
        let raw = l.model.densities.value.clone().narrow(1, 0, 1);
        render_views(&l.model, raw, &l.world, &l.info.geometry, &views, options).unwrap()
    };
    assert_eq!(queried, render(&cfg.geometry.projection.options()));
    // The cone-beam affine splat differs from the exact integral (here by ~1e-3 in line integral).
    let affine = render(&prism_render::ProjectOptions::default());
    let gap = queried
        .iter()
        .zip(affine.iter())
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(gap > 1e-5, "exact and affine renders agree to {gap:e}");
}

/// The promise of the wgpu backend: the same training loop (stage 1 with densification, stage 2
/// with GSC-Net, evaluation) runs there and follows the CPU run. Runs on lavapipe without a GPU.
#[cfg(feature = "wgpu")]
#[test]
fn a_4dsg_run_on_wgpu_follows_the_cpu_run() {
    let scene = three_channel_scene();
    let mut cfg = tiny(FourDsgMethod::Full);
    cfg.spectral.stage2.iterations = 20;
    cfg.spectral.stage2.curve_model.width = 8;
    cfg.spectral.stage2.curve_model.depth = 1;
    let run_with = |device: &burn::tensor::Device| {
        let dir = tempfile::tempdir().unwrap();
        let report = run_on(&cfg, &scene, dir.path(), device).unwrap();
        (losses(dir.path()), report)
    };
    let (cpu_log, cpu) = run_with(&cpu_device());
    let (gpu_log, gpu) = run_with(&crate::device::DeviceChoice::Wgpu.device().unwrap());
    // The kernels agree to ≤ 1e-5 relative per call (the parity tests); over 60 Adam steps
    // the losses drift apart by ~1e-4 relative (measured 1.1e-4), with the same densification.
    assert_eq!(cpu_log.len(), gpu_log.len());
    for (c, g) in cpu_log.iter().zip(&gpu_log) {
        assert_eq!(
            (&c.0, c.1, c.3),
            (&g.0, g.1, g.3),
            "{cpu_log:?} {gpu_log:?}"
        );
        assert!((c.2 - g.2).abs() <= 1e-3 * c.2, "{cpu_log:?} {gpu_log:?}");
    }
    // Measured ≤ 1e-4 dB apart.
    for (c, g) in cpu.channels.iter().zip(&gpu.channels) {
        assert!((c.scores.psnr - g.scores.psnr).abs() < 0.01, "{c:?} {g:?}");
    }
}
