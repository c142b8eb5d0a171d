use super::*;
use ndarray::Array3;
use rand::{Rng, SeedableRng};

fn mono(kevs: &[f64]) -> Vec<ChannelSpec> {
    kevs.iter().map(|&kev| ChannelSpec::Mono { kev }).collect()
}

/// Channel values of the fractions `x` under `d`'s channel matrix.
fn forward(d: &Decomposition, x: &[f64]) -> Vec<f64> {
    d.matrix()
        .iter()
        .map(|row| row.iter().zip(x).map(|(a, x)| a * x).sum())
        .collect()
}

#[test]
fn noise_free_mixtures_are_recovered_exactly() {
    // Water, bone and iodine seen at 40/60/80/100 keV: any non-negative mixture is recovered to
    // rounding. Water and bone differ only in their photoelectric-to-Compton ratio, so the
    // matrix is poorly conditioned (184) though separable: noise is what it amplifies.
    let d = Decomposition::new(Basis::body(), &mono(&[40.0, 60.0, 80.0, 100.0])).unwrap();
    let c = d.separability.condition;
    assert!((150.0..250.0).contains(&c), "{:?}", d.separability);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    for _ in 0..200 {
        let x = [
            rng.random::<f64>(),
            rng.random::<f64>() * 0.5,
            rng.random::<f64>() * 0.01,
        ];
        let got = d.solve(&forward(&d, &x));
        for (g, w) in got.iter().zip(x) {
            assert!((g - w).abs() < 1e-9, "{got:?} vs {x:?}");
        }
    }
}

#[test]
fn solutions_satisfy_the_non_negative_least_squares_optimality_conditions() {
    // KKT: with g = Aᵀ(Ax − μ), every positive fraction has g = 0 and every zero one g ≥ 0.
    // Inputs outside the basis' cone (adipose, air, negative noise) exercise the constraints.
    let d = Decomposition::new(Basis::body(), &mono(&[30.0, 36.0, 60.0, 90.0])).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    for _ in 0..500 {
        let mu: Vec<f64> = (0..4).map(|_| rng.random::<f64>() * 0.1 - 0.03).collect();
        let x = d.solve(&mu);
        let r: Vec<f64> = forward(&d, &x)
            .iter()
            .zip(&mu)
            .map(|(a, m)| a - m)
            .collect();
        let scale: f64 = mu.iter().map(|m| m.abs()).sum::<f64>() * 10.0;
        for (b, xb) in x.iter().enumerate() {
            let g: f64 = d.matrix().iter().zip(&r).map(|(a, r)| a[b] * r).sum();
            assert!(*xb >= 0.0);
            if *xb > 0.0 {
                assert!(g.abs() < 1e-12 * scale, "{x:?} {g}");
            } else {
                assert!(g > -1e-12 * scale, "{x:?} {g}");
            }
        }
    }
    // All channels at or below zero: nothing.
    assert_eq!(d.solve(&[-0.01, 0.0, -0.02, -0.001]), vec![0.0; 3]);
}

#[test]
fn channels_that_cannot_separate_the_basis_are_refused_naming_the_pair() {
    let e = Decomposition::new(Basis::body(), &mono(&[40.0, 80.0]))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("at least 3 channels"), "{e}");
    // Water and soft tissue attenuate nearly in proportion at every energy.
    let basis = Basis::new(&[Material::Water, Material::SoftTissue]).unwrap();
    let e = Decomposition::new(basis, &mono(&[60.0, 80.0, 100.0]))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("water") && e.contains("soft_tissue"), "{e}");
    assert!(Basis::new(&[Material::Water, Material::Water]).is_err());
    assert!(Basis::new(&[]).is_err());
}

#[test]
fn the_noise_gain_is_the_least_squares_standard_deviation() {
    // One basis material: fraction = aᵀμ / aᵀa, whose standard deviation under unit channel noise
    // is 1/‖a‖.
    let basis = Basis::new(&[Material::Water]).unwrap();
    let d = Decomposition::new(basis, &mono(&[40.0, 70.0])).unwrap();
    let a: Vec<f64> = [40.0, 70.0]
        .iter()
        .map(|&e| Material::Water.mu(e).unwrap())
        .collect();
    let norm = (a[0] * a[0] + a[1] * a[1]).sqrt();
    assert!((d.separability.noise_gain[0] * norm - 1.0).abs() < 1e-12);
    assert!((d.separability.condition - 1.0).abs() < 1e-12);
    // Three materials: the empirical spread of the unconstrained fractions under Gaussian noise
    // matches the gains (well inside the basis' cone, the constraints are inactive).
    let d = Decomposition::new(Basis::body(), &mono(&[40.0, 60.0, 80.0, 100.0])).unwrap();
    let x = [1.0, 0.3, 0.01];
    let clean = forward(&d, &x);
    let sigma = 1e-5;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let normal = rand_distr::Normal::new(0.0, sigma).unwrap();
    let n = 4000;
    let mut var = [0.0f64; 3];
    for _ in 0..n {
        let mu: Vec<f64> = clean.iter().map(|v| v + rng.sample(normal)).collect();
        for (v, (g, w)) in var.iter_mut().zip(d.solve(&mu).iter().zip(x)) {
            *v += (g - w).powi(2) / n as f64;
        }
    }
    for (b, v) in var.iter().enumerate() {
        let want = d.separability.noise_gain[b] * sigma;
        // 4000 samples: the standard deviation's estimate is within ±5 % at 3σ.
        assert!(
            (v.sqrt() / want - 1.0).abs() < 0.05,
            "{b}: {} vs {want}",
            v.sqrt()
        );
    }
}

#[test]
fn virtual_monoenergetic_images_follow_the_basis_attenuation() {
    let basis = Basis::body();
    let d = Decomposition::new(basis.clone(), &mono(&[40.0, 60.0, 80.0])).unwrap();
    let x = [0.9, 0.2, 0.004];
    let channels: Vec<Array3<f32>> = forward(&d, &x)
        .into_iter()
        .map(|v| Array3::from_elem((2, 3, 4), v as f32))
        .collect();
    let views: Vec<_> = channels.iter().map(|c| c.view()).collect();
    let fractions = d.volumes(&views).unwrap();
    for (f, w) in fractions.iter().zip(x) {
        assert!(
            f.iter().all(|v| (*v as f64 - w).abs() < 1e-5 * w.max(0.1)),
            "{f:?}"
        );
    }
    // At an observed energy the VMI is that channel's volume; at 55 keV the mixture's μ(55).
    let at60 = vmi(&basis, &fractions, 60.0).unwrap();
    assert!(
        at60.iter()
            .zip(channels[1].iter())
            .all(|(a, b)| (a - b).abs() < 1e-6)
    );
    let want: f64 = basis
        .mu(55.0)
        .unwrap()
        .iter()
        .zip(x)
        .map(|(m, x)| m * x)
        .sum();
    let at55 = vmi(&basis, &fractions, 55.0).unwrap();
    assert!(at55.iter().all(|v| (*v as f64 / want - 1.0).abs() < 1e-5));
    assert!(vmi(&basis, &fractions, 200.0).is_err());
    assert!(vmi(&basis, &fractions[..2], 60.0).is_err());
}

#[test]
fn basis_equivalents_are_unit_vectors_for_the_basis_and_close_for_tissues() {
    let basis = Basis::body();
    let energies: Vec<f64> = (40..=100).map(f64::from).collect();
    for (i, m) in basis.materials().iter().enumerate() {
        let e = basis.equivalent(*m, &energies).unwrap();
        for (j, v) in e.iter().enumerate() {
            let want = if i == j { 1.0 } else { 0.0 };
            assert!((v - want).abs() < 1e-9, "{m:?}: {e:?}");
        }
    }
    // Soft tissue (ICRU-44, 1.06 g/cm³) is water-like: about 1.06 water with little else, and
    // its equivalent reproduces its attenuation to < 1 % over the fitted range.
    let e = basis.equivalent(Material::SoftTissue, &energies).unwrap();
    assert!(
        (e[0] - 1.06).abs() < 0.1 && e[1].abs() < 0.05 && e[2].abs() < 1e-3,
        "{e:?}"
    );
    for &kev in &energies {
        let fit: f64 = basis
            .mu(kev)
            .unwrap()
            .iter()
            .zip(&e)
            .map(|(m, x)| m * x)
            .sum();
        let want = Material::SoftTissue.mu(kev).unwrap();
        assert!(
            (fit / want - 1.0).abs() < 0.01,
            "{kev} keV: {fit} vs {want}"
        );
    }
    assert!(basis.equivalent(Material::Adipose, &[60.0, 80.0]).is_err());
    // Fat lies outside the cone of water, bone and iodine: its equivalent stays non-negative.
    let fat = basis.equivalent(Material::Adipose, &energies).unwrap();
    assert!(fat.iter().all(|&v| v >= 0.0) && fat[0] > 0.8, "{fat:?}");
}

/// Stated error of the photoelectric + Klein–Nishina pair on water and cortical bone over
/// 40–150 keV (largest relative error at the table's energies; measured 0.18 % and 0.13 %).
const PE_COMPTON_ERROR: f64 = 0.005;
/// Stated error of water + bone on soft tissue and adipose over 40–150 keV (measured 0.006 %
/// and 0.036 %).
const WATER_BONE_ERROR: f64 = 0.002;

/// Least-squares coefficients of `f ≈ Σ_j c_j g_j` over sample points (normal equations, 2
/// functions), relative (each residual divided by `f`), and the largest relative error.
fn fit2(f: &[f64], g: [&[f64]; 2]) -> ([f64; 2], f64) {
    let w: Vec<f64> = f.iter().map(|v| 1.0 / v).collect();
    let dot = |a: &[f64], b: &[f64]| -> f64 {
        a.iter()
            .zip(b)
            .zip(&w)
            .map(|((a, b), w)| a * b * w * w)
            .sum()
    };
    let (a11, a12, a22) = (dot(g[0], g[0]), dot(g[0], g[1]), dot(g[1], g[1]));
    let (b1, b2) = (dot(g[0], f), dot(g[1], f));
    let det = a11 * a22 - a12 * a12;
    let c = [(b1 * a22 - b2 * a12) / det, (a11 * b2 - a12 * b1) / det];
    let worst = f
        .iter()
        .enumerate()
        .map(|(i, v)| ((c[0] * g[0][i] + c[1] * g[1][i]) / v - 1.0).abs())
        .fold(0.0, f64::max);
    (c, worst)
}

/// The Klein–Nishina cross-section per electron at `kev`, in units of 2π r_e².
fn klein_nishina(kev: f64) -> f64 {
    let e = kev / 510.998_95;
    let l = (1.0 + 2.0 * e).ln();
    (1.0 + e) / (e * e) * (2.0 * (1.0 + e) / (1.0 + 2.0 * e) - l / e) + l / (2.0 * e)
        - (1.0 + 3.0 * e) / ((1.0 + 2.0 * e) * (1.0 + 2.0 * e))
}

#[test]
fn two_physical_terms_span_body_attenuation_between_edges() {
    // Between absorption edges a body material's μ(E) is, to within coherent scattering and the
    // E⁻³ law's approximation, a photoelectric term ∝ E⁻³ plus a Compton term ∝ the
    // Klein–Nishina cross-section. So (i) that pair reproduces the tabulated μ(E) of water and
    // cortical bone over 40–150 keV, and (ii) water and bone, the basis the 4D-SG basis head
    // uses, reproduce other body materials (soft tissue, adipose): what lets a basis-head run
    // predict a channel it never saw. Errors are relative, at every table energy in range.
    let kevs: Vec<f64> = (40..=150).step_by(5).map(f64::from).collect();
    let mu = |m: Material| -> Vec<f64> { kevs.iter().map(|&e| m.mu(e).unwrap()).collect() };
    let pe: Vec<f64> = kevs.iter().map(|e| e.powi(-3)).collect();
    let kn: Vec<f64> = kevs.iter().map(|&e| klein_nishina(e)).collect();
    for m in [Material::Water, Material::CorticalBone] {
        let (c, worst) = fit2(&mu(m), [&pe, &kn]);
        eprintln!(
            "{m:?} ≈ {:.4e}·E⁻³ + {:.4e}·σ_KN: worst {worst:.4}",
            c[0], c[1]
        );
        assert!(c[0] > 0.0 && c[1] > 0.0, "{m:?}: {c:?}");
        assert!(worst < PE_COMPTON_ERROR, "{m:?}: {worst}");
    }
    let (w, b) = (mu(Material::Water), mu(Material::CorticalBone));
    for m in [Material::SoftTissue, Material::Adipose] {
        let (c, worst) = fit2(&mu(m), [&w, &b]);
        eprintln!(
            "{m:?} ≈ {:.4}·water + {:.4}·bone: worst {worst:.5}",
            c[0], c[1]
        );
        assert!(worst < WATER_BONE_ERROR, "{m:?}: {worst}");
    }
}
