use super::*;
use ndarray::{Axis, ShapeBuilder};

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(f64::MIN_POSITIVE)
}

fn mono(kev: f64) -> ChannelSpec {
    ChannelSpec::Mono { kev }
}

fn poly(kvp: u32) -> ChannelSpec {
    ChannelSpec::Polychromatic {
        kvp,
        filtration: Filtration::Al2_5,
    }
}

/// Quadrature nodes (keV, weight) of a 2.5 mm Al tube spectrum, built by hand: 1 keV bin centres,
/// except the 33–34 keV bin, whose fluence splits at the iodine K-edge (33.1694 keV) in
/// proportion to width, each piece at its midpoint.
fn tube_nodes(kvp: u32) -> Vec<(f64, f64)> {
    let s = Spectrum::tube(kvp, Filtration::Al2_5).unwrap();
    let k = 33.1694;
    let mut nodes = Vec::new();
    for (&e, &w) in s.energies_kev.iter().zip(&s.weights) {
        if e == 33.5 {
            nodes.push((0.5 * (33.0 + k), w * (k - 33.0)));
            nodes.push((0.5 * (k + 34.0), w * (34.0 - k)));
        } else {
            nodes.push((e, w));
        }
    }
    nodes
}

/// A single-pixel projection of `mm` of water.
fn water_p(spec: &ChannelSpec, mm: f32) -> f64 {
    let l = Array3::from_elem((1, 1, 1), mm);
    spec.project(&[(Material::Water, l)]).unwrap()[[0, 0, 0]] as f64
}

/// Fractions of a 32³ phantom: a water cylinder, a bone rod, an iodine-enhanced rod.
fn phantom() -> Vec<(Material, Array3<f32>)> {
    let n = 32;
    let c = |i: usize| i as f32 + 0.5 - n as f32 / 2.0;
    let water = Array3::from_shape_fn(
        (n, n, n),
        |(_, y, x)| {
            if c(x).hypot(c(y)) < 14.0 { 1.0 } else { 0.0 }
        },
    );
    let bone = Array3::from_shape_fn((n, n, n), |(_, y, x)| {
        if (c(x) - 5.0).hypot(c(y)) < 4.0 {
            0.6
        } else {
            0.0
        }
    });
    let iodine = Array3::from_shape_fn((n, n, n), |(z, y, x)| {
        if (c(x) + 5.0).hypot(c(y) - 3.0) < 3.0 && z > 8 {
            0.004
        } else {
            0.0
        }
    });
    vec![
        (Material::Water, water),
        (Material::CorticalBone, bone),
        (Material::Iodine, iodine),
    ]
}

/// Parallel projection along z with voxel size `dz` mm: path lengths `[1][y][x]`, summed in f64.
fn along_z(a: &Array3<f32>, dz: f64) -> Array3<f32> {
    a.mapv(|v| v as f64)
        .sum_axis(Axis(0))
        .mapv(|v| (v * dz) as f32)
        .insert_axis(Axis(0))
}

#[test]
fn serde_shape_labels_and_coordinates() {
    let yaml = "- {kind: mono, kev: 40}\n\
                - {kind: mixed, lambda: 0.3, low_kvp: 80, high_kvp: 140}\n\
                - {kind: polychromatic, kvp: 80}\n\
                - {kind: polychromatic, kvp: 120, filtration: al2.5_cu0.2}\n\
                - {kind: window, lo_kev: 20, hi_kev: 90, kvp: 120}\n";
    let specs: Vec<ChannelSpec> = serde_yaml_ng::from_str(yaml).unwrap();
    let labels: Vec<String> = specs.iter().map(|s| s.label()).collect();
    assert_eq!(
        labels,
        [
            "40keV",
            "lambda0.3",
            "80kVp",
            "120kVp_al2.5_cu0.2",
            "20-90keV"
        ]
    );
    let coords: Vec<f64> = specs.iter().map(|s| s.coordinate()).collect();
    assert_eq!(coords, [40.0, 0.3, 80.0, 120.0, 20.0]);
    assert_eq!(
        specs[1],
        ChannelSpec::Mixed {
            lambda: 0.3,
            low_kvp: 80,
            high_kvp: 140,
            filtration: Filtration::Al2_5
        }
    );
    let back: Vec<ChannelSpec> =
        serde_yaml_ng::from_str(&serde_yaml_ng::to_string(&specs).unwrap()).unwrap();
    assert_eq!(back, specs);
    // A misspelt field is an error, not a silently defaulted value.
    let typo = serde_yaml_ng::from_str::<ChannelSpec>("{kind: polychromatic, kvp: 80, filter: x}");
    assert!(typo.unwrap_err().to_string().contains("filter"));
    for s in &specs {
        s.validate().unwrap();
    }
}

#[test]
fn mono_is_linear_and_matches_the_table() {
    let spec = mono(60.0);
    let l1 = Array3::from_shape_fn((2, 3, 4), |(v, r, c)| (v + r + c) as f32 * 1.5);
    let l2 = Array3::from_shape_fn((2, 3, 4), |(v, r, c)| ((v * 7 + r * 3 + c) % 5) as f32);
    let zero = Array3::zeros((2, 3, 4));
    let p = |a: &Array3<f32>, b: &Array3<f32>| {
        spec.project(&[
            (Material::Water, a.clone()),
            (Material::CorticalBone, b.clone()),
        ])
        .unwrap()
    };
    let both = p(&l1, &l2);
    let sum = p(&l1, &zero) + p(&zero, &l2);
    let scaled = p(&(&l1 * 3.0), &(&l2 * 3.0));
    let (mw, mb) = (
        Material::Water.mu(60.0).unwrap(),
        Material::CorticalBone.mu(60.0).unwrap(),
    );
    for ((idx, &v), (&s, &t)) in both.indexed_iter().zip(sum.iter().zip(&scaled)) {
        let want = mw * l1[idx] as f64 + mb * l2[idx] as f64;
        assert!((v as f64 - want).abs() <= 1e-6 * want.max(1e-3), "{idx:?}");
        assert!((v - s).abs() <= 1e-6 * v.abs().max(1e-3));
        assert!((t - 3.0 * v).abs() <= 3e-6 * v.abs().max(1e-3));
    }
}

#[test]
fn volume_and_projection_agree_for_linear_channels() {
    // For mono and mixed channels, projecting the reference volume (Σ_z μ·dz) must equal the
    // channel synthesised from the projected fractions: both are Σ_m c_m Σ_z f_m dz. The
    // only difference is f32 rounding of the two orders of summation (~1e-6 relative).
    let fractions = phantom();
    let dz = 0.8;
    let paths: Vec<(Material, Array3<f32>)> = fractions
        .iter()
        .map(|(m, f)| (*m, along_z(f, dz)))
        .collect();
    for spec in [
        mono(33.0),
        mono(33.5),
        mono(70.0),
        ChannelSpec::Mixed {
            lambda: 0.3,
            low_kvp: 80,
            high_kvp: 140,
            filtration: Filtration::Al2_5Cu0_2,
        },
    ] {
        let vol = spec.volume(&fractions).unwrap();
        let p = spec.project(&paths).unwrap();
        let p_vol = along_z(&vol, dz);
        let peak = p.iter().fold(0f32, |a, &b| a.max(b));
        assert!(peak > 0.1, "{spec:?}");
        for (a, b) in p.iter().zip(p_vol.iter()) {
            assert!((a - b).abs() <= 2e-6 * peak, "{spec:?}: {a} vs {b}");
        }
    }
    // A 30 mm water slab: volume value × thickness = p, for every channel kind's thin limit.
    let slab = (Material::Water, Array3::from_elem((4, 1, 1), 1.0f32));
    let spec = mono(50.0);
    let mu = spec.volume(std::slice::from_ref(&slab)).unwrap()[[0, 0, 0]] as f64;
    assert!(rel(water_p(&spec, 30.0), mu * 30.0) < 1e-6);
}

#[test]
fn mixed_blends_kvp_effective_coefficients() {
    let mixed = |lambda| ChannelSpec::Mixed {
        lambda,
        low_kvp: 80,
        high_kvp: 140,
        filtration: Filtration::Al2_5,
    };
    // μ̄ computed independently from the spectrum and the table.
    let mu_bar = |kvp| {
        tube_nodes(kvp)
            .iter()
            .map(|&(e, w)| w * Material::Iodine.mu(e).unwrap())
            .sum::<f64>()
    };
    let (lo, hi) = (mu_bar(80), mu_bar(140));
    for lambda in [0.0, 0.3, 1.0] {
        let got = mixed(lambda).effective_mu(Material::Iodine).unwrap();
        let want = lambda * lo + (1.0 - lambda) * hi;
        assert!(rel(got, want) < 1e-12, "{lambda}");
    }
    assert!(rel(poly(80).effective_mu(Material::Iodine).unwrap(), lo) < 1e-12);
    // Lower kVp attenuates more.
    let water: Vec<f64> = [40, 80, 140]
        .map(|k| poly(k).effective_mu(Material::Water).unwrap())
        .to_vec();
    assert!(water[0] > water[1] && water[1] > water[2], "{water:?}");
}

#[test]
fn polychromatic_zero_thickness_is_exactly_zero() {
    for spec in [
        poly(40),
        poly(140),
        ChannelSpec::Window {
            lo_kev: 33.2,
            hi_kev: 47.7,
            kvp: 120,
            filtration: Filtration::Al2_5Cu0_2,
        },
    ] {
        let zeros: Vec<(Material, Array3<f32>)> = Material::ALL
            .iter()
            .map(|&m| (m, Array3::zeros((2, 2, 3))))
            .collect();
        let p = spec.project(&zeros).unwrap();
        assert!(p.iter().all(|&v| v == 0.0), "{spec:?}: {p:?}");
    }
}

#[test]
fn polychromatic_water_hardens() {
    for kvp in [40, 80, 140] {
        let spec = poly(kvp);
        let mu_bar = spec.effective_mu(Material::Water).unwrap();
        // Thin limit: slope at zero is μ̄. p(L) = μ̄L − ½Var_S(μ)L² + …; at L = 1e-3 mm the
        // relative deviation is ½Var/μ̄·L < 1e-4 for water (Var ≤ 0.01 mm⁻², μ̄ ≥ 0.02 mm⁻¹).
        assert!(rel(water_p(&spec, 1e-3) / 1e-3, mu_bar) < 1e-4, "{kvp}");
        let mut prev_mu_eff = f64::INFINITY;
        for l in [1.0, 10.0, 50.0, 100.0, 200.0, 400.0] {
            let (p1, p2) = (water_p(&spec, l), water_p(&spec, 2.0 * l));
            assert!(p2 < 2.0 * p1 && p2 > p1, "{kvp} kVp, {l} mm: {p1} {p2}");
            let mu_eff = p1 / l as f64;
            assert!(mu_eff < prev_mu_eff && mu_eff < mu_bar, "{kvp} kVp, {l} mm");
            prev_mu_eff = mu_eff;
            // Independent naive evaluation of −ln Σ S e^(−μL) (safe at these thicknesses).
            let naive = -tube_nodes(kvp)
                .iter()
                .map(|&(e, w)| w * (-Material::Water.mu(e).unwrap() * l as f64).exp())
                .sum::<f64>()
                .ln();
            assert!(rel(p1, naive) < 1e-6, "{kvp} kVp, {l} mm: {p1} vs {naive}");
        }
    }
}

#[test]
fn log_sum_exp_is_stable_and_exact_on_two_bins() {
    // Two equal bins, μ = 1 and 3 mm⁻¹: p(L) = −ln(½e^(−L) + ½e^(−3L)).
    let weights = [0.5, 0.5];
    let mu = [1.0, 3.0];
    let l = [0.0f32, 0.5, 2.0, 50.0, 1e4];
    let p = polychromatic(&weights, &[(&mu, &l)]);
    for (&li, &pi) in l.iter().zip(&p) {
        let li = li as f64;
        // Closed form rearranged to stay finite: L + ln 2 − ln(1 + e^(−2L)).
        let want = li + 2f64.ln() - (-2.0 * li).exp().ln_1p();
        let want = if li == 0.0 { 0.0 } else { want };
        assert!(
            (pi as f64 - want).abs() <= 1e-6 * want.max(1e-6),
            "{li}: {pi} vs {want}"
        );
    }
    // Naive evaluation underflows to +∞ at 1e4 mm; ours is finite.
    assert!(p[4].is_finite());
}

#[test]
fn narrow_window_approaches_mono_at_its_centre() {
    let l = |mm| Array3::from_elem((1, 1, 1), mm);
    let paths = vec![
        (Material::Water, l(150.0)),
        (Material::CorticalBone, l(20.0)),
    ];
    let err = |centre: f64, half: f64| {
        let p_mono = mono(centre).project(&paths).unwrap()[[0, 0, 0]] as f64;
        let spec = ChannelSpec::Window {
            lo_kev: centre - half,
            hi_kev: centre + half,
            kvp: 100,
            filtration: Filtration::Al2_5,
        };
        rel(spec.project(&paths).unwrap()[[0, 0, 0]] as f64, p_mono)
    };
    // Centred on the 60 keV bin edge: the window keeps a sub-bin either side of 60 keV, whose
    // energies converge to 60 keV as the window shrinks.
    let errs = [
        err(60.0, 10.0),
        err(60.0, 3.0),
        err(60.0, 0.5),
        err(60.0, 0.05),
    ];
    assert!(errs.windows(2).all(|w| w[1] < w[0]), "{errs:?}");
    assert!(errs[3] < 1e-3, "{errs:?}");
    // Inside one 1 keV bin the window is one sub-bin at its centre: mono up to f32 rounding.
    assert!(err(60.4, 0.05) < 1e-6);
}

#[test]
fn bins_straddling_the_k_edge_are_split_at_the_edge() {
    // A window holding exactly the 33–34 keV bin: 16.94 % of its photons lie below the edge.
    let spec = ChannelSpec::Window {
        lo_kev: 33.0,
        hi_kev: 34.0,
        kvp: 80,
        filtration: Filtration::Al2_5,
    };
    let i = Material::Iodine;
    let k = 33.1694;
    let want =
        (k - 33.0) * i.mu(0.5 * (33.0 + k)).unwrap() + (34.0 - k) * i.mu(0.5 * (k + 34.0)).unwrap();
    assert!(rel(spec.effective_mu(i).unwrap(), want) < 1e-12);
    // Beer–Lambert on the two sub-bins, for 0.2 mm of iodine.
    let p = spec
        .project(&[(i, Array3::from_elem((1, 1, 1), 0.2f32))])
        .unwrap()[[0, 0, 0]] as f64;
    let below = (k - 33.0) * (-0.2 * i.mu(0.5 * (33.0 + k)).unwrap()).exp();
    let above = (34.0 - k) * (-0.2 * i.mu(0.5 * (k + 34.0)).unwrap()).exp();
    assert!(rel(p, -(below + above).ln()) < 1e-6);
}

#[test]
fn windows_straddling_the_iodine_k_edge_separate_iodine() {
    let win = |lo, hi| ChannelSpec::Window {
        lo_kev: lo,
        hi_kev: hi,
        kvp: 120,
        filtration: Filtration::Al2_5,
    };
    let ratio = |spec: ChannelSpec| {
        spec.effective_mu(Material::Iodine).unwrap() / spec.effective_mu(Material::Water).unwrap()
    };
    // Iodine/water contrast jumps by the K-edge ratio (~5) across 33.17 keV.
    assert!(ratio(win(34.0, 40.0)) > 3.0 * ratio(win(27.0, 33.0)));
}

#[test]
fn bad_inputs_name_their_fields() {
    let check = |r: Result<Array3<f32>>, field: &str| {
        let msg = r.unwrap_err().to_string();
        assert!(msg.contains(field), "expected `{field}` in: {msg}");
    };
    let paths = vec![(Material::Water, Array3::from_elem((1, 2, 2), 10.0f32))];
    check(mono(5.0).project(&paths), "`kev`");
    check(mono(151.0).project(&paths), "10-150 keV");
    for lambda in [-0.1, 1.5, f64::NAN] {
        let spec = ChannelSpec::Mixed {
            lambda,
            low_kvp: 80,
            high_kvp: 140,
            filtration: Filtration::Al2_5,
        };
        check(spec.project(&paths), "`lambda`");
    }
    let spec = ChannelSpec::Mixed {
        lambda: 0.5,
        low_kvp: 70,
        high_kvp: 140,
        filtration: Filtration::Al2_5,
    };
    check(spec.volume(&paths), "`low_kvp`");
    check(poly(90).project(&paths), "`kvp`");
    check(poly(90).project(&paths), "40, 60, 80, 100, 120, 140");
    let empty = ChannelSpec::Window {
        lo_kev: 90.0,
        hi_kev: 100.0,
        kvp: 80,
        filtration: Filtration::Al2_5,
    };
    check(empty.project(&paths), "lo_kev..hi_kev");
    check(mono(60.0).project(&[]), "`paths`");
    check(mono(60.0).volume(&[]), "`fractions`");
    let mut two = paths.clone();
    two.push((Material::Iodine, Array3::zeros((1, 2, 3))));
    check(poly(80).project(&two), "paths[1] (iodine)");
    let mut nan = paths.clone();
    nan[0].1[[0, 1, 0]] = f32::NAN;
    check(poly(80).project(&nan), "paths[0] (water)");
}

#[test]
fn non_standard_layout_inputs_are_accepted() {
    let c = Array3::from_shape_fn((2, 3, 4), |(v, r, c)| (v * 12 + r * 4 + c) as f32);
    let mut f = Array3::zeros(c.raw_dim().f());
    f.assign(&c);
    let spec = poly(100);
    let a = spec.project(&[(Material::Water, c)]).unwrap();
    let b = spec.project(&[(Material::Water, f)]).unwrap();
    assert_eq!(a, b);
}

/// The nodes a model uses to imitate the synthesis give back `project`'s line integrals (f64
/// sum of w·exp(−Σμ·L), then −ln) for every channel kind, and a linear channel is one node.
#[test]
fn nodes_reproduce_the_synthesis() {
    let mats = [Material::Water, Material::CorticalBone, Material::Iodine];
    let lengths = [[0.0f32, 0.0, 0.0], [30.0, 0.0, 0.0], [120.0, 25.0, 0.4]];
    let specs = [
        mono(60.0),
        poly(80),
        ChannelSpec::Window {
            lo_kev: 30.0,
            hi_kev: 50.0,
            kvp: 120,
            filtration: Filtration::Al2_5,
        },
        ChannelSpec::Mixed {
            lambda: 0.3,
            low_kvp: 80,
            high_kvp: 140,
            filtration: Filtration::Al2_5,
        },
    ];
    for spec in &specs {
        let nodes = spec.nodes(&mats).unwrap();
        let total: f64 = nodes.iter().map(|n| n.0).sum();
        assert!(
            (total - 1.0).abs() < 1e-12,
            "{spec:?}: weights sum to {total}"
        );
        if matches!(spec, ChannelSpec::Mono { .. } | ChannelSpec::Mixed { .. }) {
            assert_eq!(nodes.len(), 1, "{spec:?} is linear");
        }
        for l in &lengths {
            let paths: Vec<_> = mats
                .iter()
                .zip(l)
                .map(|(&m, &x)| (m, Array3::from_elem((1, 1, 1), x)))
                .collect();
            let want = spec.project(&paths).unwrap()[[0, 0, 0]] as f64;
            let sum: f64 = nodes
                .iter()
                .map(|(w, mu)| {
                    w * (-mu.iter().zip(l).map(|(u, x)| u * *x as f64).sum::<f64>()).exp()
                })
                .sum();
            let got = -sum.ln();
            // project returns f32: its rounding bounds the difference.
            assert!(
                (got - want).abs() <= 1e-6 * want.abs().max(1.0),
                "{spec:?} at {l:?}: nodes give {got}, project {want}"
            );
        }
    }
}
