//! [`CurveModel`]: GSC-Net or the MLP ablation behind one checked entry point.

use crate::init::SeedStream;
use burn::module::{Module, Param};
use burn::tensor::{Device, Int, Tensor, TensorData};

use crate::config::{CurveModelConfig, CurveModelKind};
use crate::grid::SpectralGrid;
use crate::gscnet::GscNet;
use crate::mlp::CurveMlp;
use crate::{Error, Result};

/// The network inside a [`CurveModel`].
// One model exists per reconstruction, so the variants' size difference (~1 KB of handles) is
// irrelevant and boxing would complicate the derived `Module`.
#[allow(clippy::large_enum_variant)]
#[derive(Module, Debug)]
pub enum CurveNet {
    Gscnet(GscNet),
    Mlp(CurveMlp),
}

/// A spectral curve model built for one observed grid of M ≥ 2 channels.
///
/// GSC-Net's basis B ∈ R^{R×M} has one column per observed grid point, so a model is tied to the
/// grid it was built for; unobserved channels are queried from the predicted curve with
/// [`crate::interpolate_curve`], not by feeding a new τ.
///
/// Δu = b + net(u⁽ᶜ⁾, τ): besides the network every model has a learnable spectral baseline
/// b ∈ R^M shared by all Gaussians (zero at init; [`CurveModel::set_baseline`] starts it from the
/// data). It carries the object-wide change of attenuation with energy, so the network only
/// learns how each Gaussian's curve departs from it, and stage 2 does not start with every
/// channel at the structural (channel-mean) densities.
#[derive(Module, Debug)]
pub struct CurveModel {
    pub net: CurveNet,
    /// The spectral baseline b [M] (raw-density units).
    pub baseline: Param<Tensor<1>>,
    channels: usize,
    /// Nodes of the û table (0: per-Gaussian evaluation), see [`CurveModelConfig::table_size`].
    table_size: usize,
}

impl CurveModelConfig {
    /// Build the configured model for `grid` on `device`, with parameters drawn from `seed`.
    ///
    /// Errors: an invalid config field (named under `curve_model`), or a grid of one channel:
    /// with M = 1 there is no spectral axis and stage 2 is skipped, so no curve model exists.
    pub fn init(&self, grid: &SpectralGrid, device: &Device, seed: u64) -> Result<CurveModel> {
        self.validate().map_err(|e| e.under("curve_model"))?;
        let m = grid.len();
        if m < 2 {
            return Err(Error::invalid(
                "tau",
                format!(
                    "the spectral grid has M = {m} channel: a curve model needs M ≥ 2; \
                     with one channel the spectral stage (stage 2) is skipped and the \
                     stage-1 densities are the result"
                ),
            ));
        }
        let mut rng = SeedStream::new(seed);
        let net = match self.kind {
            CurveModelKind::Gscnet => CurveNet::Gscnet(GscNet::new(&mut rng, self, m, device)),
            CurveModelKind::Mlp => CurveNet::Mlp(CurveMlp::new(&mut rng, self, device)),
        };
        let baseline = Param::from_tensor(Tensor::zeros([m], device));
        Ok(CurveModel {
            net,
            baseline,
            channels: m,
            table_size: self.table_size,
        })
    }
}

impl CurveModel {
    /// Number of observed channels M the model was built for.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Start the spectral baseline b [M] from `values` (e.g. the raw-density offsets that turn
    /// the structural densities into each channel's).
    ///
    /// Errors: not M values, or a non-finite value (field `baseline`).
    pub fn set_baseline(&mut self, values: &[f32]) -> Result<()> {
        if values.len() != self.channels || values.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "baseline",
                format!("needs M = {} finite values, got {values:?}", self.channels),
            ));
        }
        let device = self.baseline.val().device();
        let t = Tensor::from_data(TensorData::new(values.to_vec(), [values.len()]), &device);
        self.baseline = Param::from_tensor(t);
        Ok(())
    }

    /// Condition the raw density around `centre` with scale `scale` (raw-density units), e.g.
    /// the stage-1 distribution's median and spread, so the Fourier features resolve the range
    /// the Gaussians occupy instead of the fixed û = u/(s + |u|).
    ///
    /// Errors: a non-finite centre, or a scale that is not finite and > 0 (field `u_scale`).
    pub fn set_density_conditioning(&mut self, centre: f32, scale: f32) -> Result<()> {
        if !(centre.is_finite() && scale.is_finite() && scale > 0.0) {
            return Err(Error::invalid(
                "u_scale",
                format!(
                    "conditioning needs a finite centre and a scale > 0, got {centre}, {scale}"
                ),
            ));
        }
        match &mut self.net {
            CurveNet::Gscnet(net) => net.tokenizer.set_conditioning(centre, scale),
            CurveNet::Mlp(net) => net.tokenizer.set_conditioning(centre, scale),
        }
        Ok(())
    }

    fn tokenizer(&self) -> &crate::tokenizer::Tokenizer {
        match &self.net {
            CurveNet::Gscnet(net) => &net.tokenizer,
            CurveNet::Mlp(net) => &net.tokenizer,
        }
    }

    fn net_forward(&self, u_hat: Tensor<1>, tau: Tensor<1>) -> Tensor<2> {
        match &self.net {
            CurveNet::Gscnet(net) => net.forward(u_hat, tau),
            CurveNet::Mlp(net) => net.forward(u_hat, tau),
        }
    }

    /// The network's curves at every Gaussian's û, read from a table of `t` nodes on [−1, 1]
    /// by cubic convolution (Catmull–Rom, Keys' a = −½): each û blends the four nodes around
    /// it with weights cubic in its offset, so the curve and its slope ∂Δu/∂û are continuous,
    /// and the error is O(h³) in value and O(h²) in slope (h = 2/(t − 1)), against O(h²) and
    /// O(h) for linear interpolation: a quarter of the nodes reach the same accuracy.
    ///
    /// Nodes û_j = −1 + (j − 1)·h for j = 0..t + 2: one beyond each end of [−1, 1], so every
    /// û in it has two nodes on either side.
    fn table_lookup(&self, u_hat: Tensor<1>, tau: Tensor<1>, t: usize) -> Tensor<2> {
        let device = u_hat.device();
        let h = 2.0 / (t - 1) as f32;
        let nodes = Tensor::<1, Int>::arange(0..(t + 2) as i64, &device)
            .float()
            .mul_scalar(h)
            .sub_scalar(1.0 + h);
        let table = self.net_forward(nodes, tau);
        crate::ops::table_lookup(table, u_hat, h)
    }

    /// Which network this is.
    pub fn kind(&self) -> CurveModelKind {
        match self.net {
            CurveNet::Gscnet(_) => CurveModelKind::Gscnet,
            CurveNet::Mlp(_) => CurveModelKind::Mlp,
        }
    }

    /// Raw density curves Δu [K, M] for common raw densities `u_c` [K] on the grid `tau` [M]
    /// (pass `grid.to_tensor(device)` of the grid the model was built for). K = 0 gives an
    /// empty `[0, M]` tensor. Only shapes are checked here (no device read-back); the grid
    /// values were checked by [`SpectralGrid::new`].
    pub fn forward(&self, u_c: Tensor<1>, tau: Tensor<1>) -> Result<Tensor<2>> {
        let [m] = tau.dims();
        if m != self.channels {
            return Err(Error::invalid(
                "tau",
                format!(
                    "has {m} grid points but the model was built for M = {} channels",
                    self.channels
                ),
            ));
        }
        let [k] = u_c.dims();
        if k == 0 {
            return Ok(Tensor::zeros([0, m], &u_c.device()));
        }
        let u_hat = self.tokenizer().condition(u_c);
        let du = match self.table_size {
            0 => self.net_forward(u_hat, tau),
            t => self.table_lookup(u_hat, tau, t),
        };
        Ok(du.add(self.baseline.val().unsqueeze_dim::<2>(0)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::{ModuleVisitor, Param};
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::TensorData;

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_into_vec().unwrap()
    }

    /// An uneven grid on [0, 1]: τ_m = (m / (M − 1))².
    fn uneven_grid(m: usize) -> SpectralGrid {
        SpectralGrid::new(
            (0..m)
                .map(|i| (i as f32 / (m - 1) as f32).powi(2))
                .collect(),
        )
        .unwrap()
    }

    fn config(kind: CurveModelKind) -> CurveModelConfig {
        CurveModelConfig {
            kind,
            ..CurveModelConfig::default()
        }
    }

    const KINDS: [CurveModelKind; 2] = [CurveModelKind::Gscnet, CurveModelKind::Mlp];

    #[test]
    fn shapes_and_finite_outputs_for_extreme_densities_and_uneven_grids() {
        let device = crate::test_util::cpu();
        let u = [-1e3f32, -30.0, 0.0, 30.0, 1e3, -2.5, 1.0];
        for kind in KINDS {
            for m in [2, 3, 8, 16] {
                let grid = uneven_grid(m);
                let model = config(kind).init(&grid, &device, 5).unwrap();
                assert_eq!((model.channels(), model.kind()), (m, kind));
                let out = model
                    .forward(Tensor::from_floats(u, &device), grid.to_tensor(&device))
                    .unwrap();
                assert_eq!(out.dims(), [7, m], "{kind:?} M = {m}");
                let v = values(out);
                assert!(v.iter().all(|x| x.is_finite()), "{kind:?} M = {m}: {v:?}");
                // The head starts near zero: stage 2 starts from the stage-1 densities.
                let max = v.iter().fold(0.0f32, |a, x| a.max(x.abs()));
                assert!(max < 0.1, "{kind:?} M = {m}: |Δu| up to {max} at init");
            }
        }
    }

    #[test]
    fn init_is_deterministic_in_the_seed() {
        let device = crate::test_util::cpu();
        let grid = uneven_grid(4);
        let run = |seed| {
            let model = CurveModelConfig::default()
                .init(&grid, &device, seed)
                .unwrap();
            let u = Tensor::from_floats([0.5f32, -1.0], &device);
            values(model.forward(u, grid.to_tensor(&device)).unwrap())
        };
        assert_eq!(run(1), run(1));
        assert_ne!(run(1), run(2));
    }

    /// The û table against per-Gaussian evaluation, values and gradients w.r.t. u, for both
    /// networks, at the default 512 nodes. Cubic convolution errs by O(h³·max|F‴|) in value and
    /// O(h²·max|F‴|) in slope, h = 2/(T − 1); F's highest Fourier frequency 2³π in û moves
    /// ωh ≈ 0.1 rad per node. The bounds are the accuracy of the linear 2048-node table this one
    /// replaced (2.5e-5 of F's scale in value, 0.9 % in slope); measured here ≤ 6.1e-6 and 1.4e-3.
    #[test]
    fn the_table_matches_per_gaussian_evaluation() {
        let device = crate::test_util::cpu().autodiff();
        let grid = uneven_grid(4);
        let u: Vec<f32> = (0..97).map(|i| -12.0 + 0.25 * i as f32).collect();
        for kind in KINDS {
            let run = |table_size| {
                let model = CurveModelConfig {
                    kind,
                    table_size,
                    ..CurveModelConfig::default()
                }
                .init(&grid, &device, 3)
                .unwrap();
                let ut = Tensor::<1>::from_data(TensorData::new(u.clone(), [u.len()]), &device)
                    .require_grad();
                let out = model.forward(ut.clone(), grid.to_tensor(&device)).unwrap();
                let grads = out.clone().sum().backward();
                (values(out), values(ut.grad(&grads).unwrap()))
            };
            let (exact, g_exact) = run(0);
            let (table, g_table) = run(512);
            let err = exact
                .iter()
                .zip(&table)
                .fold(0.0f32, |a, (x, y)| a.max((x - y).abs()));
            let g_err = g_exact
                .iter()
                .zip(&g_table)
                .fold(0.0f32, |a, (x, y)| a.max((x - y).abs()));
            let scale = exact.iter().fold(0.0f32, |a, x| a.max(x.abs()));
            let g_scale = g_exact.iter().fold(0.0f32, |a, x| a.max(x.abs()));
            println!(
                "{kind:?}: |Δu| ≤ {scale:.3e}, table error {err:.3e}; |∂/∂u| ≤ {g_scale:.3e}, error {g_err:.3e}"
            );
            assert!(
                scale > 0.0 && err <= 2.5e-5 * scale,
                "{kind:?}: {err} vs {scale}"
            );
            assert!(
                g_scale > 0.0 && g_err <= 9e-3 * g_scale,
                "{kind:?}: {g_err} vs {g_scale}"
            );
        }
    }

    #[test]
    fn conditioning_around_a_centre_is_a_shift_of_the_input() {
        let device = crate::test_util::cpu();
        let grid = uneven_grid(3);
        for kind in KINDS {
            let plain = config(kind).init(&grid, &device, 4).unwrap();
            let mut centred = config(kind).init(&grid, &device, 4).unwrap();
            centred.set_density_conditioning(-3.0, 4.0).unwrap();
            let u = [-5.0f32, -3.0, -1.5, 0.5];
            let shifted = u.map(|v| v + 3.0);
            let a = plain
                .forward(
                    Tensor::from_floats(shifted, &device),
                    grid.to_tensor(&device),
                )
                .unwrap();
            let b = centred
                .forward(Tensor::from_floats(u, &device), grid.to_tensor(&device))
                .unwrap();
            for (x, y) in values(a).iter().zip(values(b)) {
                // u − c and (u + 3) − 0 round differently by at most an ulp of u.
                assert!((x - y).abs() <= 1e-5, "{kind:?}: {x} vs {y}");
            }
            for (c, s) in [(f32::NAN, 1.0), (0.0, 0.0), (0.0, f32::INFINITY)] {
                let e = centred.set_density_conditioning(c, s).unwrap_err();
                assert_eq!(e.field(), "u_scale");
            }
        }
    }

    #[test]
    fn the_baseline_shifts_every_curve_by_exactly_b() {
        let device = crate::test_util::cpu();
        let grid = uneven_grid(3);
        for kind in KINDS {
            let mut model = config(kind).init(&grid, &device, 2).unwrap();
            let u = Tensor::<1>::from_floats([-2.0f32, 0.0, 3.0], &device);
            let before = values(model.forward(u.clone(), grid.to_tensor(&device)).unwrap());
            let b = [0.75f32, -0.25, -1.5];
            model.set_baseline(&b).unwrap();
            let after = values(model.forward(u, grid.to_tensor(&device)).unwrap());
            for (i, (x, y)) in before.iter().zip(&after).enumerate() {
                // One f32 addition: exact up to the rounding of the sum.
                assert!(
                    (y - (x + b[i % 3])).abs() <= 1e-6,
                    "{kind:?} [{i}]: {x} + b → {y}"
                );
            }
            for bad in [&[0.0f32, 1.0][..], &[0.0, f32::NAN, 1.0]] {
                assert_eq!(model.set_baseline(bad).unwrap_err().field(), "baseline");
            }
        }
    }

    #[test]
    fn bad_grids_sizes_and_configs_are_rejected_with_named_fields() {
        let device = crate::test_util::cpu();
        for kind in KINDS {
            let one = SpectralGrid::new(vec![0.5]).unwrap();
            let e = config(kind).init(&one, &device, 0).unwrap_err();
            assert_eq!(e.field(), "tau");
            assert!(e.to_string().contains("stage 2") && e.to_string().contains("skipped"));

            let grid = uneven_grid(3);
            let model = config(kind).init(&grid, &device, 0).unwrap();
            let u = Tensor::<1>::from_floats([0.0f32, 1.0], &device);
            let e = model
                .forward(u.clone(), uneven_grid(4).to_tensor(&device))
                .unwrap_err();
            assert_eq!(e.field(), "tau");
            assert!(e.to_string().contains("M = 3"));
            // K = 0 (everything pruned) is an empty curve set, not an error.
            let empty = model
                .forward(Tensor::<1>::zeros([0], &device), grid.to_tensor(&device))
                .unwrap();
            assert_eq!(empty.dims(), [0, 3]);
        }
        let bad = CurveModelConfig {
            conv_kernel: 2,
            ..CurveModelConfig::default()
        };
        let e = bad.init(&uneven_grid(3), &device, 0).unwrap_err();
        assert_eq!(e.field(), "curve_model.conv_kernel");
    }

    /// Collects, for every float parameter, whether its gradient exists, is finite and non-zero.
    struct GradientAudit<'a> {
        grads: &'a burn::tensor::Gradients,
        seen: usize,
        problems: Vec<String>,
    }

    impl ModuleVisitor for GradientAudit<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.seen += 1;
            let shape = param.val().dims();
            match param.val().grad(self.grads) {
                None => self.problems.push(format!("{shape:?}: no gradient")),
                Some(g) => {
                    let g = values(g);
                    if !g.iter().all(|v| v.is_finite()) {
                        self.problems
                            .push(format!("{shape:?}: non-finite gradient"));
                    } else if g.iter().all(|&v| v == 0.0) {
                        self.problems.push(format!("{shape:?}: all-zero gradient"));
                    }
                }
            }
        }
    }

    #[test]
    fn every_parameter_receives_a_finite_nonzero_gradient() {
        let device = crate::test_util::cpu().autodiff();
        for kind in KINDS {
            let grid = uneven_grid(5);
            let model = config(kind).init(&grid, &device, 9).unwrap();
            let u = Tensor::<1>::from_floats([-1e3f32, -3.0, 0.0, 2.0, 1e3], &device);
            let out = model.forward(u, grid.to_tensor(&device)).unwrap();
            let r = Tensor::<2>::from_data(
                TensorData::new((0..25).map(|i| (i as f32 * 0.7).sin()).collect(), [5, 5]),
                &device,
            );
            let grads = out.mul(r).sum().backward();
            let mut audit = GradientAudit {
                grads: &grads,
                seen: 0,
                problems: Vec::new(),
            };
            model.visit(&mut audit);
            assert!(audit.seen > 5, "{kind:?}: only {} parameters", audit.seen);
            assert!(audit.problems.is_empty(), "{kind:?}: {:?}", audit.problems);
        }
    }

    /// A smooth target curve set: Δu*(u, τ) = 0.5 tanh(u/4)(1 − τ) + 0.3 sin(πτ) − 0.2 τ².
    fn target(u: f32, tau: f32) -> f32 {
        0.5 * (u / 4.0).tanh() * (1.0 - tau) + 0.3 * (std::f32::consts::PI * tau).sin()
            - 0.2 * tau * tau
    }

    fn fit(kind: CurveModelKind) -> (f32, f32) {
        let device = crate::test_util::cpu().autodiff();
        let grid = SpectralGrid::new(vec![0.0, 0.15, 0.4, 0.7, 1.0]).unwrap();
        let u: Vec<f32> = (0..12).map(|i| -6.0 + i as f32 * (10.0 / 11.0)).collect();
        let t: Vec<f32> = u
            .iter()
            .flat_map(|&ui| grid.values().iter().map(move |&tm| target(ui, tm)))
            .collect();
        let u = Tensor::<1>::from_data(TensorData::new(u, [12]), &device);
        let t = Tensor::<2>::from_data(TensorData::new(t, [12, 5]), &device);
        let tau = grid.to_tensor(&device);
        let cfg = CurveModelConfig {
            kind,
            width: 16,
            state_size: 4,
            ..CurveModelConfig::default()
        };
        let mut model = cfg.init(&grid, &device, 21).unwrap();
        let mut optim = AdamConfig::new().init();
        let mut first = None;
        let mut last = f32::NAN;
        for _ in 0..300 {
            let pred = model.forward(u.clone(), tau.clone()).unwrap();
            let loss = pred.sub(t.clone()).powi_scalar(2).mean();
            last = values(loss.clone())[0];
            first.get_or_insert(last);
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            model = optim.step(1e-2, model, grads);
        }
        let first = first.unwrap();
        println!("{kind:?}: L2 loss {first:.3e} → {last:.3e} in 300 Adam steps");
        (first, last)
    }

    #[test]
    fn gscnet_fits_a_smooth_curve_set() {
        let (first, last) = fit(CurveModelKind::Gscnet);
        assert!(last < first / 50.0, "GSC-Net L2 loss {first} → {last}");
    }

    #[test]
    fn mlp_fits_a_smooth_curve_set() {
        let (first, last) = fit(CurveModelKind::Mlp);
        assert!(last < first / 50.0, "MLP L2 loss {first} → {last}");
    }
}
