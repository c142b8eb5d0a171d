use super::*;
use crate::observe::Silent;
use crate::physics::Material;
use crate::projector::Joseph;

/// A small cone-beam phantom config: 24³ volume, 32² detector, 6 + 2 views, three mono channels.
fn tiny_config() -> SimulateConfig {
    tiny_config_with("phantom: { radius_mm: 110.0 }")
}

/// [`tiny_config`] with another `object` (YAML under `object:`, indented by two spaces).
fn tiny_config_with(object: &str) -> SimulateConfig {
    serde_yaml_ng::from_str(&format!(
        r#"
name: tiny
seed: 7
geometry:
  beam: cone
  dso: 1000.0
  dsd: 1500.0
  detector: {{ rows: 32, cols: 32, size_mm: [512.0, 512.0] }}
  volume: {{ n: 24, size_mm: 256.0 }}
  views: 6
  test_views: 2
object:
  {object}
channels:
  - {{ kind: mono, kev: 40 }}
  - {{ kind: mono, kev: 70 }}
  - {{ kind: mono, kev: 100 }}
"#
    ))
    .unwrap()
}

fn rel_l2(a: &Array3<f32>, b: &Array3<f32>) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

#[test]
fn phantom_scene_is_valid_and_ordered() {
    let scene = simulate(&tiny_config(), None, &Silent).unwrap();
    assert_eq!(scene.projections.shape(), &[3, 8, 32, 32]);
    assert_eq!(scene.split.train, (0..6).collect::<Vec<_>>());
    assert_eq!(scene.split.test, vec![6, 7]);
    let taus: Vec<f64> = scene.channels.iter().map(|c| c.tau).collect();
    assert_eq!(taus, vec![0.0, 0.5, 1.0]);
    // Attenuation falls with energy: every channel's total line integral is below the previous one.
    let totals: Vec<f32> = (0..3).map(|c| scene.channel_projections(c).sum()).collect();
    assert!(totals[0] > totals[1] && totals[1] > totals[2], "{totals:?}");
    // Test angles lie in [0, 2π) and are sorted.
    let test = &scene.geometry.angles_rad[6..];
    assert!(test[0] <= test[1] && test[1] < 2.0 * PI && test[0] >= 0.0);
}

#[test]
fn projections_agree_with_the_reference_volumes() {
    // Exact analytic projections vs the Joseph projection of the voxelised reference: they differ
    // only by discretisation (partial volumes at 10.7 mm voxels, Joseph interpolation), a few % in
    // relative L2. An axis flip, a transposed volume or a wrong unit would give ≳ 30 %.
    let cfg = tiny_config();
    let scene = simulate(&cfg, None, &Silent).unwrap();
    let projector = Joseph::new(&scene.geometry).unwrap();
    let references = scene.references.as_ref().unwrap();
    for c in 0..3 {
        let fp = projector
            .forward(references.index_axis(Axis(0), c))
            .unwrap();
        let err = rel_l2(&fp, &scene.channel_projections(c).to_owned());
        assert!(err < 0.06, "channel {c}: relative L2 {err}");
    }
}

#[test]
fn noise_touches_training_views_only_and_is_seeded() {
    let clean = simulate(&tiny_config(), None, &Silent).unwrap();
    let mut cfg = tiny_config();
    cfg.noise = Some(NoiseModel {
        i0: 1e4,
        electronic_sigma: 2.0,
    });
    let a = simulate(&cfg, None, &Silent).unwrap();
    let b = simulate(&cfg, None, &Silent).unwrap();
    assert_eq!(a.projections, b.projections, "same seed, same noise");
    let train = s![.., ..6, .., ..];
    let test = s![.., 6.., .., ..];
    assert_ne!(a.projections.slice(train), clean.projections.slice(train));
    assert_eq!(a.projections.slice(test), clean.projections.slice(test));
}

#[test]
fn missing_pairs_are_unavailable_and_zeroed() {
    let mut cfg = tiny_config();
    cfg.missing = vec![[2, 1], [4, 0]];
    let scene = simulate(&cfg, None, &Silent).unwrap();
    assert!(!scene.availability[[2, 1]] && !scene.availability[[4, 0]]);
    assert_eq!(scene.availability.iter().filter(|a| !**a).count(), 2);
    assert_eq!(scene.projections.slice(s![1, 2, .., ..]).sum(), 0.0);
    assert!(scene.projections.slice(s![0, 2, .., ..]).sum() > 0.0);
}

#[test]
fn interleaved_channels_take_turns_over_the_training_views_only() {
    let mut cfg = tiny_config();
    cfg.acquisition.views = ViewSharing::Interleaved;
    cfg.missing = vec![[0, 0]];
    let scene = simulate(&cfg, None, &Silent).unwrap();
    for v in 0..8 {
        let expect: Vec<usize> = match v {
            0 => vec![],
            1..6 => vec![v % 3],
            _ => vec![0, 1, 2],
        };
        assert_eq!(scene.available_channels(v), expect, "view {v}");
        for c in 0..3 {
            let sum = scene.projections.slice(s![c, v, .., ..]).sum();
            assert_eq!(
                sum > 0.0,
                expect.contains(&c),
                "view {v} channel {c}: {sum}"
            );
        }
    }
    let yaml = "name: t\nviews: interleaved\n";
    let e = serde_yaml_ng::from_str::<Acquisition>(yaml)
        .unwrap_err()
        .to_string();
    assert!(e.contains("name"), "{e}");
}

/// Photon-counting bins split one exposure: the air pixels' line-integral variance is
/// 1/(i0·share) (Poisson counts, first order), so a bin with a quarter of the photons is twice
/// as noisy (in σ) as a channel with all of them.
#[test]
fn split_photons_give_each_bin_its_share_of_the_noise_budget() {
    let mut cfg = tiny_config_with("phantom: { radius_mm: 20.0 }");
    cfg.channels = vec![
        ChannelSpec::Window {
            lo_kev: 20.0,
            hi_kev: 100.0,
            kvp: 100,
            filtration: Default::default(),
        },
        ChannelSpec::Window {
            lo_kev: 60.0,
            hi_kev: 100.0,
            kvp: 100,
            filtration: Default::default(),
        },
    ];
    cfg.noise = Some(NoiseModel {
        i0: 1.0e4,
        electronic_sigma: 0.0,
    });
    cfg.acquisition.photons = PhotonSharing::Split;
    let scene = simulate(&cfg, None, &Silent).unwrap();
    for (c, spec) in cfg.channels.iter().enumerate() {
        let share = spec.photon_share().unwrap();
        // Air: the detector's outer columns (the 20 mm phantom covers the middle few).
        let air: Vec<f64> = scene
            .projections
            .slice(s![c, ..6, .., ..4])
            .iter()
            .map(|&x| x as f64)
            .collect();
        let n = air.len() as f64;
        let mean = air.iter().sum::<f64>() / n;
        let var = air.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let expect = 1.0 / (1.0e4 * share);
        // 768 samples: the sample variance's relative standard error is √(2/767) ≈ 5 %.
        assert!(
            (var / expect - 1.0).abs() < 0.2,
            "channel {c}: share {share}, var {var} vs {expect}"
        );
    }
    let shares: Vec<f64> = cfg
        .channels
        .iter()
        .map(|c| c.photon_share().unwrap())
        .collect();
    // The 100 kVp tube has < 1 % of its photons below 20 keV and about a quarter above 60 keV.
    assert!(shares[0] > 0.98 && shares[0] < 1.0, "{shares:?}");
    assert!(shares[1] > 0.2 && shares[1] < 0.3, "{shares:?}");
}

#[test]
fn hu_volume_scene_projects_its_fractions() {
    // A synthetic HU object stored as int16 (z, y, x): a water cylinder in the lower 3/4 of the
    // volume with a bone rod off-centre in x and y, running through the lower half only, so that
    // any axis flip or transpose between fractions and projections breaks the agreement below.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hu.npy");
    let n = 20;
    let hu = Array3::from_shape_fn((n, n, n), |(z, y, x)| {
        let r = ((x as f64 - 9.5).powi(2) + (y as f64 - 9.5).powi(2)).sqrt();
        let rod = ((x as f64 - 12.5).powi(2) + (y as f64 - 8.0).powi(2)).sqrt();
        if rod < 2.5 && z < 10 {
            1000i16
        } else if r < 8.0 && z < 15 {
            0
        } else {
            -1000
        }
    });
    ndarray_npy::write_npy(&path, &hu).unwrap();
    let mut cfg = tiny_config();
    cfg.object = ObjectSpec::Hu {
        path: path.clone(),
        voxel_mm: [10.0, 10.0, 10.0],
        mapping: HuMapping::default(),
    };
    cfg.geometry.volume.size_mm = 200.0;
    let scene = simulate(&cfg, None, &Silent).unwrap();
    assert!(scene.provenance.source_data[0].ends_with("hu.npy"));
    let projector = Joseph::new(&scene.geometry).unwrap();
    let references = scene.references.as_ref().unwrap();
    for c in 0..3 {
        let fp = projector
            .forward(references.index_axis(Axis(0), c))
            .unwrap();
        let err = rel_l2(&fp, &scene.channel_projections(c).to_owned());
        for axis in 0..3 {
            let mut flipped = references.index_axis(Axis(0), c).to_owned();
            flipped.invert_axis(Axis(axis));
            let bad = rel_l2(
                &projector.forward(flipped.view()).unwrap(),
                &scene.channel_projections(c).to_owned(),
            );
            assert!(
                bad > 4.0 * err,
                "channel {c}: flipping axis {axis} gives {bad} vs {err}"
            );
        }
        // Measured 1.2–1.5 % (discretisation of a 10 mm HU grid onto 8.3 mm voxels).
        assert!(err < 0.04, "channel {c}: relative L2 {err}");
    }
}

#[test]
fn bad_configs_name_the_field() {
    let mut cfg = tiny_config();
    cfg.channels.clear();
    let e = simulate(&cfg, None, &Silent).unwrap_err().to_string();
    assert!(e.contains("`channels`"), "{e}");

    let mut cfg = tiny_config();
    cfg.missing = vec![[99, 0]];
    let e = simulate(&cfg, None, &Silent).unwrap_err().to_string();
    assert!(e.contains("`missing[0]`"), "{e}");

    let mut cfg = tiny_config();
    cfg.geometry.dso = -5.0;
    let e = simulate(&cfg, None, &Silent).unwrap_err().to_string();
    assert!(e.contains("`geometry.dso`"), "{e}");

    let mut cfg = tiny_config();
    cfg.channels[1] = ChannelSpec::Mono { kev: 400.0 };
    let e = simulate(&cfg, None, &Silent).unwrap_err().to_string();
    assert!(e.contains("channels[1]"), "{e}");

    let mut cfg = tiny_config();
    cfg.channels.swap(0, 2);
    let e = simulate(&cfg, None, &Silent).unwrap_err().to_string();
    assert!(
        e.contains("channels[1].coordinate") || e.contains("channels[2].coordinate"),
        "{e}"
    );

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.yaml");
    std::fs::write(&path, "name: x\ngeometry: {beam: cone}\n").unwrap();
    let e = SimulateConfig::load(&path).unwrap_err().to_string();
    assert!(e.contains("c.yaml"), "{e}");

    let mut cfg = tiny_config();
    cfg.object = ObjectSpec::Hu {
        path: dir.path().join("absent.npy"),
        voxel_mm: [1.0; 3],
        mapping: HuMapping::default(),
    };
    let e = simulate(&cfg, None, &Silent).unwrap_err().to_string();
    assert!(e.contains("absent.npy"), "{e}");
}

#[test]
fn every_shipped_config_parses() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "yaml") {
            let cfg = SimulateConfig::load(&path).unwrap();
            cfg.geometry.build(cfg.seed).unwrap();
            for ch in &cfg.channels {
                ch.validate().unwrap();
            }
            n += 1;
        }
    }
    assert!(n >= 6, "found {n} configs");
}

#[test]
fn a_phantom_insert_adds_its_materials() {
    // A 40×40×80 mm iron rod replacing water: its voxelised iron fraction integrates to the
    // ellipsoid's volume 4/3·π·20·20·40 mm³ up to the 3³-point sampling of each 10.7 mm voxel
    // (a few % at this size); one water delta of −1 leaves no water inside it.
    let mut cfg = tiny_config_with(
        "phantom:\n    radius_mm: 110.0\n    inserts:\n      - { label: rod, ellipsoid: \
         { centre: [0, 20, 0], semi_axes: [20, 20, 40] }, materials: [[water, -1.0], [iron, 1.0]] }",
    );
    let geometry = cfg.geometry.build(cfg.seed).unwrap();
    let used = cfg.object.materials_used().unwrap();
    assert!(used.contains(&Material::Iron) && !used.contains(&Material::Titanium));
    let data = cfg.object.materials(&geometry, &Silent).unwrap();
    let (_, iron) = data
        .fractions
        .iter()
        .find(|(m, _)| *m == Material::Iron)
        .unwrap();
    let voxel_mm3 = (256.0f64 / 24.0).powi(3);
    let volume = iron.iter().map(|&f| f as f64).sum::<f64>() * voxel_mm3;
    let exact = 4.0 / 3.0 * PI * 20.0 * 20.0 * 40.0;
    assert!((volume / exact - 1.0).abs() < 0.05, "{volume} vs {exact}");
    assert!(iron.iter().all(|&f| (0.0..=1.0 + 1e-6).contains(&f)));

    // A bad insert is refused, naming it.
    if let ObjectSpec::Phantom { inserts, .. } = &mut cfg.object {
        inserts[0].ellipsoid.semi_axes[1] = -1.0;
    }
    let e = simulate(&cfg, None, &Silent).unwrap_err().to_string();
    assert!(
        e.contains("object.phantom.inserts[0].ellipsoid.semi_axes"),
        "{e}"
    );
}

#[test]
fn disturbed_scans_store_seeded_poses_with_the_stated_spread() {
    // 400 views of σ = 0.5 mm detector shifts and σ = 1° spins and tilts: each view's deviation,
    // measured back from its vectors against the circular pose, has zero mean and the stated σ
    // (sample std within 15 %, about 4 standard errors at 400 draws).
    let mut cfg = tiny_config();
    cfg.geometry.views = 400;
    cfg.geometry.test_views = 0;
    let circular = cfg.geometry.build(cfg.seed).unwrap();
    cfg.geometry.disturb = Some(DisturbSpec {
        source_mm: 2.0,
        detector_mm: 0.5,
        spin_deg: 1.0,
        tilt_deg: 1.0,
    });
    let g = cfg.geometry.build(cfg.seed).unwrap();
    let nominal = Geometry {
        vectors: None,
        ..g.clone()
    };
    assert_eq!(
        nominal, circular,
        "the circular fields stay the nominal scan"
    );
    assert_eq!(g, cfg.geometry.build(cfg.seed).unwrap(), "seeded");
    let (was, now) = (circular.to_vectors(), g.vectors.clone().unwrap());
    let unit = |a: [f64; 3]| {
        let n = crate::geometry::dot(a, a).sqrt();
        a.map(|x| x / n)
    };
    let (mut shift, mut spin, mut source) = (vec![], vec![], vec![]);
    for (a, b) in was.iter().zip(&now) {
        let d = [0, 1, 2].map(|k| b.detector[k] - a.detector[k]);
        shift.push(crate::geometry::dot(d, unit(a.u)));
        shift.push(crate::geometry::dot(d, unit(a.v)));
        source.extend((0..3).map(|k| b.source[k] - a.source[k]));
        // The spin: the turned u's component along the old v (tilts change it at second order).
        spin.push(
            crate::geometry::dot(unit(b.u), unit(a.v))
                .asin()
                .to_degrees(),
        );
    }
    let stats = |x: &[f64]| {
        let n = x.len() as f64;
        let m = x.iter().sum::<f64>() / n;
        (
            m,
            (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt(),
        )
    };
    for (what, x, sigma) in [
        ("shift", &shift, 0.5),
        ("spin", &spin, 1.0),
        ("source", &source, 2.0),
    ] {
        let (m, s) = stats(x);
        eprintln!("{what}: mean {m:+.4}, std {s:.4} (σ {sigma})");
        assert!(
            m.abs() < 4.0 * sigma / (x.len() as f64).sqrt(),
            "{what} mean {m}"
        );
        assert!((s / sigma - 1.0).abs() < 0.15, "{what} std {s}");
    }
    // Zero spread is the circular scan itself.
    cfg.geometry.disturb = Some(DisturbSpec::default());
    assert_eq!(
        cfg.geometry.build(cfg.seed).unwrap().vectors.unwrap(),
        circular.to_vectors()
    );
    // A parallel beam has no source to move; errors name the field.
    cfg.geometry.beam = Beam::Parallel;
    cfg.geometry.disturb = Some(DisturbSpec {
        source_mm: 1.0,
        ..DisturbSpec::default()
    });
    let e = cfg.geometry.build(cfg.seed).unwrap_err().to_string();
    assert!(e.contains("disturb.source_mm"), "{e}");
}
