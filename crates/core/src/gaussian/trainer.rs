//! The training loop shared by R²-Gaussian, 4D-SG stage 1 and the per-channel density fit.
//!
//! Each iteration draws one training view (without replacement until every view was used, then
//! reshuffled; seeded), renders every density column supervised at that view in one projection,
//! and minimises `L1 + λ_dssim·(1 − SSIM) + λ_tv·TV(32³ patch)`. Terms with weight 0 are not
//! computed. Adam steps the learnable groups (log-linear learning rates); when densification is
//! on, the view-space gradient statistics are accumulated and clone/split/prune runs on schedule
//! (after that iteration's Adam step; upstream skips the step at those iterations).

use super::adam::LogLinear;
use super::densify::{DensifyConfig, DensifyCounts, densify_and_prune};
use super::log::{LogRecord, LossTerms, RunLog};
use super::loss::{SsimWindow, l1, total_variation};
use super::model::{GaussianModel, Learnable, softplus};
use super::world::World;
use crate::geometry::VolumeGrid;
use crate::metrics::{SsimParams, psnr, ssim_3d};
use crate::{Error, Result};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Int, Tensor, TensorData};
use indicatif::ProgressBar;
use ndarray::{Array3, Array4, Axis};
use prism_gscnet::{CurveModel, curve_regularizer};
use prism_render::{
    Camera, Gaussians, ProjectOptions, VoxelGrid, VoxelizeOptions, project, screen_grad_norm,
    screen_probe, voxelize,
};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Learning rates per parameter group (normalised world; upstream R²-Gaussian defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LearningRates {
    pub position: LogLinear,
    pub density: LogLinear,
    pub scale: LogLinear,
    pub rotation: LogLinear,
}

impl Default for LearningRates {
    fn default() -> Self {
        let ll = |init, end| LogLinear { init, end };
        LearningRates {
            position: ll(2e-4, 2e-5),
            density: ll(1e-2, 1e-3),
            scale: ll(5e-3, 5e-4),
            rotation: ll(1e-3, 1e-4),
        }
    }
}

impl LearningRates {
    pub fn validate(&self) -> Result<()> {
        self.position.validate("lr.position")?;
        self.density.validate("lr.density")?;
        self.scale.validate("lr.scale")?;
        self.rotation.validate("lr.rotation")
    }
}

/// Loss weights (YAML `loss:`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossConfig {
    /// Weight of `1 − SSIM` on projections (upstream 0.25; 0 skips SSIM).
    pub lambda_dssim: f64,
    /// Weight of the TV of a random voxelized patch (upstream 0.05; 0 skips the voxelization).
    pub lambda_tv: f64,
    /// Edge of the TV patch in voxels of the reconstruction grid (upstream 32).
    pub tv_patch: usize,
}

impl Default for LossConfig {
    fn default() -> Self {
        LossConfig {
            lambda_dssim: 0.25,
            lambda_tv: 0.05,
            tv_patch: 32,
        }
    }
}

impl LossConfig {
    pub fn validate(&self) -> Result<()> {
        for (f, v) in [
            ("loss.lambda_dssim", self.lambda_dssim),
            ("loss.lambda_tv", self.lambda_tv),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(
                    f,
                    format!("must be finite and ≥ 0, got {v}"),
                ));
            }
        }
        if self.lambda_tv > 0.0 && self.tv_patch < 2 {
            return Err(Error::invalid("loss.tv_patch", "must be at least 2 voxels"));
        }
        Ok(())
    }
}

/// One training view: its camera (normalised world) and the supervised density columns.
pub struct View {
    pub camera: Camera,
    /// Normalised line integrals `[1, n, rows, cols]` of the supervised columns.
    pub target: Tensor<4>,
    /// The density columns supervised here (increasing), when not all of them.
    pub columns: Option<Tensor<1, Int>>,
}

/// What a stage fits: views and the number of density columns the model renders.
pub struct Supervision {
    pub views: Vec<View>,
    pub columns: usize,
}

/// Reference volumes to score the model against during training.
pub struct Evaluator {
    /// Reconstruction grid (millimetres) and the world the model lives in.
    pub grid: VolumeGrid,
    pub world: World,
    /// One reference (mm⁻¹, `[z][y][x]`) per density column.
    pub references: Vec<Array3<f32>>,
}

impl Evaluator {
    /// Voxelize the model on the reconstruction grid: `[M][z][y][x]` in mm⁻¹.
    pub fn volumes(&self, model: &GaussianModel) -> Result<Array4<f32>> {
        volumes(model, &self.grid, &self.world)
    }

    /// Mean PSNR / SSIM over columns, after dividing both volumes by the reference's maximum.
    pub fn score(&self, model: &GaussianModel) -> Result<(f64, f64)> {
        self.score_volumes(self.volumes(model)?)
    }

    /// [`Evaluator::score`] with the model's densities replaced by raw columns `[K, M]`.
    pub fn score_raw(&self, model: &GaussianModel, raw: Tensor<2>) -> Result<(f64, f64)> {
        self.score_volumes(volumes_with(model, raw, &self.grid, &self.world)?)
    }

    fn score_volumes(&self, vols: Array4<f32>) -> Result<(f64, f64)> {
        let (mut p, mut s) = (0.0, 0.0);
        for (c, truth) in self.references.iter().enumerate() {
            let (a, b) = score_volume(vols.index_axis(Axis(0), c).to_owned(), truth)?;
            p += a;
            s += b;
        }
        let n = self.references.len().max(1) as f64;
        Ok((p / n, s / n))
    }
}

/// PSNR / SSIM (R²-Gaussian conventions) of `pred` against `truth`, both divided by the
/// reference's maximum.
pub fn score_volume(pred: Array3<f32>, truth: &Array3<f32>) -> Result<(f64, f64)> {
    let peak = truth.fold(0.0f32, |a, &b| a.max(b));
    if peak <= 0.0 {
        return Err(Error::invalid(
            "references",
            "a reference volume has no positive value",
        ));
    }
    let t = truth.mapv(|x| x / peak);
    let p = pred.mapv(|x| x / peak);
    Ok((
        psnr(p.view(), t.view(), 1.0)?,
        ssim_3d(p.view(), t.view(), &SsimParams::default())?.mean,
    ))
}

/// Voxelize `model` on `grid` (millimetres): `[M][z][y][x]` densities in mm⁻¹.
pub fn volumes(model: &GaussianModel, grid: &VolumeGrid, world: &World) -> Result<Array4<f32>> {
    voxelize_gaussians(model.activate(None).gaussians, grid, world)
}

/// [`volumes`] with the model's densities replaced by raw columns `raw` `[K, M]`.
pub fn volumes_with(
    model: &GaussianModel,
    raw: Tensor<2>,
    grid: &VolumeGrid,
    world: &World,
) -> Result<Array4<f32>> {
    let mut g = model.activate(None).gaussians;
    g.densities = softplus(raw);
    voxelize_gaussians(g, grid, world)
}

fn voxelize_gaussians(g: Gaussians, grid: &VolumeGrid, world: &World) -> Result<Array4<f32>> {
    let v =
        voxelize(&g, &world.voxel_grid(grid), &VoxelizeOptions::default()).map_err(render_error)?;
    let [m, z, y, x] = v.dims();
    let data = super::host_values(&v);
    let scale = world.density_scale as f32;
    Ok(Array4::from_shape_vec((m, z, y, x), data)
        .expect("shape of the voxelized volume")
        .mapv(|v| v * scale))
}

pub(crate) fn render_error(e: prism_render::RenderError) -> Error {
    Error::invalid("render", e.to_string())
}

/// The settings of one training stage.
pub struct Stage<'a> {
    /// Name in the log (`r2gs`, `geometry`, `densities`, and `gscnet` or `mlp` for stage 2).
    pub name: &'a str,
    /// What is fitted, for the log (`structural`, a channel label, `all`).
    pub channel: &'a str,
    pub iterations: usize,
    pub learn: Learnable,
    pub lr: &'a LearningRates,
    pub loss: &'a LossConfig,
    /// How the training views are rendered.
    pub projection: ProjectOptions,
    pub densify: Option<&'a DensifyConfig>,
    /// Evaluate (voxelize and score) every this many iterations and at the end; 0: only at the end.
    pub eval_every: usize,
    /// Grid of the TV patch's voxel size and of the volume box (millimetres).
    pub grid: &'a VolumeGrid,
    pub world: &'a World,
    pub seed: u64,
}

/// Stage 2 of 4D-SG: the model's density column is the common raw density u⁽ᶜ⁾ [K, 1] and a
/// curve model (GSC-Net or the MLP) predicts Δu [K, M] on the observed spectral grid; the rendered
/// densities are softplus(u⁽ᶜ⁾ + Δu). The network has its own Adam (Burn's module optimiser).
pub struct CurveFit {
    /// The curve model, on the autodiff form of the training device.
    pub net: CurveModel,
    pub optim: ModuleOptimizer,
    /// The observed grid τ [M] (autodiff device).
    pub tau: Tensor<1>,
    /// Weight of the curve smoothness term L_curve.
    pub lambda_curve: f64,
    /// Learning rate of the network.
    pub lr: LogLinear,
}

impl CurveFit {
    /// Raw per-channel densities u⁽ᶜ⁾ + Δu `[K, M]` of `model` (no gradient), for saving and
    /// for queries.
    pub fn raw_densities(&self, model: &GaussianModel) -> Result<Tensor<2>> {
        let u = model.densities.value.clone();
        let k = u.dims()[0];
        let du = self
            .net
            .forward(u.clone().autodiff().reshape([k]), self.tau.clone())
            .map_err(|e| Error::invalid("curve_model", e.to_string()))?
            .inner();
        Ok(u + du)
    }
}

/// Seconds spent per part of an iteration, summed over a stage. On the CPU backends each part
/// is its own work; on wgpu the ops only queue, and the forward and backward are paid where the
/// loss terms are read back, which is counted under `backward`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    pub render: f64,
    pub loss: f64,
    pub backward: f64,
    pub optimiser: f64,
    pub densify: f64,
}

/// Summary of one stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    pub stage: String,
    pub channel: String,
    pub iterations: usize,
    /// Training seconds of this stage (evaluation excluded).
    pub train_s: f64,
    pub timing: Timing,
    pub densify: DensifyCounts,
    pub n_gaussians: usize,
    pub final_loss: LossTerms,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
}

/// Train `model` on `sup` for one stage; records go to `log`.
pub fn train(
    model: &mut GaussianModel,
    sup: &Supervision,
    eval: Option<&Evaluator>,
    stage: &Stage,
    mut curve: Option<&mut CurveFit>,
    log: &mut RunLog,
    bar: &ProgressBar,
) -> Result<StageReport> {
    stage.lr.validate()?;
    stage.loss.validate()?;
    if let Some(d) = stage.densify {
        d.validate()?;
    }
    if sup.views.is_empty() {
        return Err(Error::invalid("views", "no training view to fit"));
    }
    let columns = match &curve {
        Some(c) => c.net.channels(),
        None => model.channels(),
    };
    if columns != sup.columns || (curve.is_some() && model.channels() != 1) {
        return Err(Error::invalid(
            "densities",
            format!(
                "the model renders {columns} density columns, the stage supervises {}",
                sup.columns
            ),
        ));
    }
    let device = model.device();
    let window = SsimWindow::new(&device.clone().autodiff());
    let mut rng = ChaCha8Rng::seed_from_u64(stage.seed);
    let mut stack: Vec<usize> = Vec::new();
    let opts = stage.projection;
    let ng = stage.world.volume(stage.grid);
    let bbox = ng.bounds();
    let start_train = log.train_s();
    let mut timing = Timing::default();
    let mut counts = DensifyCounts::default();
    let mut window_loss = (LossTerms::default(), 0usize);
    let mut last = LossTerms::default();
    let mut last_score: Option<(f64, f64)> = None;
    let densify = stage.densify.filter(|_| stage.learn.position);
    let mut stats = densify.map(|_| GradStats::new(model.len(), &device));
    bar.set_length(stage.iterations as u64);
    bar.set_position(0);
    let cols = sup.views[0].camera.cols;
    let rows = sup.views[0].camera.rows;
    // Pixel → NDC gradient units (R²-Gaussian's densification threshold is in NDC).
    let ndc = (rows + cols) as f32 / 4.0;

    for it in 1..=stage.iterations {
        if stack.is_empty() {
            stack = (0..sup.views.len()).collect();
            stack.shuffle(&mut rng);
        }
        let view = &sup.views[stack.pop().expect("refilled")];

        let t0 = Instant::now();
        let mut act = model.activate(Some(stage.learn));
        let delta_u = match &curve {
            Some(c) => {
                let u = act.leaves[3].clone();
                let k = u.dims()[0];
                let du = c
                    .net
                    .forward(u.clone().reshape([k]), c.tau.clone())
                    .map_err(|e| Error::invalid("curve_model", e.to_string()))?;
                act.gaussians.densities = softplus(u + du.clone());
                Some(du)
            }
            None => None,
        };
        let probe = stats.as_ref().map(|_| screen_probe(&act.gaussians, 1));
        let mut img = project(
            &act.gaussians,
            std::slice::from_ref(&view.camera),
            probe.as_ref(),
            &opts,
        )
        .map_err(render_error)?;
        if let Some(c) = &view.columns {
            img = img.select(1, c.clone());
        }
        let t1 = Instant::now();

        let l_1 = l1(img.clone(), view.target.clone());
        let mut total = l_1.clone();
        let dssim = (stage.loss.lambda_dssim > 0.0).then(|| {
            let d = window.ssim(img.clone(), view.target.clone()).neg() + 1.0;
            total = total.clone() + d.clone() * stage.loss.lambda_dssim;
            d
        });
        let tv = if stage.loss.lambda_tv > 0.0 {
            let patch = tv_patch(&ng, stage.loss.tv_patch, &mut rng);
            let v = voxelize(&act.gaussians, &patch, &VoxelizeOptions::default())
                .map_err(render_error)?;
            let tv = total_variation(v);
            total = total.clone() + tv.clone() * stage.loss.lambda_tv;
            Some(tv)
        } else {
            None
        };
        let l_curve = match (&curve, delta_u) {
            (Some(c), Some(du)) if c.lambda_curve > 0.0 => {
                let l = curve_regularizer(du)
                    .map_err(|e| Error::invalid("curve_model", e.to_string()))?;
                total = total.clone() + l.clone() * c.lambda_curve;
                Some(l)
            }
            _ => None,
        };
        let t2 = Instant::now();

        // The loss terms are read back once, after the backward pass is queued: one device
        // sync per iteration on wgpu (absent terms read as 0).
        let packed = Tensor::cat(
            [
                Some(&total),
                Some(&l_1),
                dssim.as_ref(),
                tv.as_ref(),
                l_curve.as_ref(),
            ]
            .map(|t| t.map_or_else(|| total.zeros_like(), |t| t.clone().detach()))
            .to_vec(),
            0,
        );
        let grads = total.backward();
        let read = super::host_values(&packed);
        let terms = LossTerms {
            total: read[0] as f64,
            l1: read[1] as f64,
            dssim: read[2] as f64,
            tv: read[3] as f64,
            curve: read[4] as f64,
        };
        let t3 = Instant::now();
        if !terms.total.is_finite() {
            return Err(Error::invalid(
                "training",
                format!(
                    "stage `{}` iteration {it}: the loss is not finite ({:?})",
                    stage.name, terms
                ),
            ));
        }

        let [lm, ls, lr_, ld] = &act.leaves;
        let lr = stage.lr;
        let n = stage.iterations;
        let groups = [
            (stage.learn.position, lm, &mut model.means, lr.position),
            (stage.learn.scale, ls, &mut model.scales, lr.scale),
            (stage.learn.rotation, lr_, &mut model.rotations, lr.rotation),
            (stage.learn.density, ld, &mut model.densities, lr.density),
        ];
        for (on, leaf, param, sched) in groups {
            if on && let Some(g) = leaf.grad(&grads) {
                param.step(g, sched.at(it - 1, n));
            }
        }
        let probe_grad = probe.as_ref().and_then(|p| p.grad(&grads));
        if let Some(c) = curve.as_deref_mut() {
            let gp = GradientsParams::from_grads(grads, &c.net);
            c.net = c.optim.step(c.lr.at(it - 1, n), c.net.clone(), gp);
        }
        let t4 = Instant::now();

        if let (Some(cfg), Some(st)) = (densify, stats.as_mut())
            && it < cfg.until
        {
            if let Some(g) = probe_grad {
                st.add(screen_grad_norm(&g) * ndc);
            }
            if cfg.due(it) {
                let host = model.to_host();
                let scores = st.scores();
                let (next, src, c) =
                    densify_and_prune(&host, &scores, &model.bounds, bbox, cfg, &mut rng);
                model.remap(&next, &src);
                counts.cloned += c.cloned;
                counts.split += c.split;
                counts.pruned += c.pruned;
                *st = GradStats::new(model.len(), &device);
                if model.is_empty() {
                    return Err(Error::invalid(
                        "densify.min_density",
                        "pruning removed every Gaussian",
                    ));
                }
            }
        }
        let t5 = Instant::now();
        timing.render += (t1 - t0).as_secs_f64();
        timing.loss += (t2 - t1).as_secs_f64();
        timing.backward += (t3 - t2).as_secs_f64();
        timing.optimiser += (t4 - t3).as_secs_f64();
        timing.densify += (t5 - t4).as_secs_f64();

        let (acc, k) = &mut window_loss;
        acc.total += terms.total;
        acc.l1 += terms.l1;
        acc.dssim += terms.dssim;
        acc.tv += terms.tv;
        acc.curve += terms.curve;
        *k += 1;
        last = terms;
        bar.set_position(it as u64);
        let due = (stage.eval_every > 0 && it % stage.eval_every == 0) || it == stage.iterations;
        if due {
            let score = match eval {
                Some(e) => Some(log.evaluating(|| match curve.as_deref() {
                    Some(c) => e.score_raw(model, c.raw_densities(model)?),
                    None => e.score(model),
                })?),
                None => None,
            };
            if score.is_some() {
                last_score = score;
            }
            let (acc, k) = std::mem::take(&mut window_loss);
            let kf = k.max(1) as f64;
            log.write(&LogRecord {
                stage: stage.name.to_string(),
                channel: stage.channel.to_string(),
                iter: it,
                wall_s: log.wall_s(),
                train_s: log.train_s(),
                loss: LossTerms {
                    total: acc.total / kf,
                    l1: acc.l1 / kf,
                    dssim: acc.dssim / kf,
                    tv: acc.tv / kf,
                    curve: acc.curve / kf,
                },
                n_gaussians: model.len(),
                psnr: score.map(|s| s.0),
                ssim: score.map(|s| s.1),
            })?;
        }
        if due || it % 10 == 0 {
            let psnr = last_score
                .map(|s| format!(" PSNR {:.2}", s.0))
                .unwrap_or_default();
            bar.set_message(format!(
                "{} {} loss {:.4e} K {}{psnr}",
                stage.name,
                stage.channel,
                last.total,
                model.len()
            ));
        }
    }
    Ok(StageReport {
        stage: stage.name.to_string(),
        channel: stage.channel.to_string(),
        iterations: stage.iterations,
        train_s: log.train_s() - start_train,
        timing,
        densify: counts,
        n_gaussians: model.len(),
        final_loss: last,
        psnr: last_score.map(|s| s.0),
        ssim: last_score.map(|s| s.1),
    })
}

/// A `p³`-voxel patch of the (normalised) grid with its centre uniform in the volume box shrunk
/// by half the patch edge (clipped to the grid when the patch is larger).
fn tv_patch(grid: &VolumeGrid, p: usize, rng: &mut impl Rng) -> VoxelGrid {
    let n = [grid.nx, grid.ny, grid.nz];
    let d = [grid.dx, grid.dy, grid.dz];
    let (lo, hi) = grid.bounds();
    let dims: [usize; 3] = std::array::from_fn(|a| p.min(n[a]));
    let offset = std::array::from_fn(|a| {
        let half = dims[a] as f64 * d[a] / 2.0;
        let (a0, a1) = (lo[a] + half, hi[a] - half);
        if a1 > a0 {
            rng.random_range(a0..a1)
        } else {
            (lo[a] + hi[a]) / 2.0
        }
    });
    VoxelGrid {
        dims,
        voxel: d,
        offset,
    }
}

/// Running sums of the view-space gradient norm (NDC units) and of the number of iterations in
/// which each Gaussian received a gradient (our visibility count).
struct GradStats {
    sum: Tensor<1>,
    count: Tensor<1>,
}

impl GradStats {
    fn new(k: usize, device: &burn::tensor::Device) -> Self {
        GradStats {
            sum: Tensor::zeros([k], device),
            count: Tensor::zeros([k], device),
        }
    }

    fn add(&mut self, norm: Tensor<1>) {
        self.count = self.count.clone() + norm.clone().greater_elem(0.0).float();
        self.sum = self.sum.clone() + norm;
    }

    /// Mean norm per Gaussian (0 where it never received a gradient).
    fn scores(&self) -> Vec<f32> {
        let s = super::host_values(&self.sum);
        let c = super::host_values(&self.count);
        s.iter()
            .zip(&c)
            .map(|(s, c)| if *c > 0.0 { s / c } else { 0.0 })
            .collect()
    }
}

/// Upload a `[n][rows][cols]` stack of normalised line integrals as `[1, n, rows, cols]`.
pub fn target_tensor(
    values: Vec<f32>,
    n: usize,
    rows: usize,
    cols: usize,
    device: &burn::tensor::Device,
) -> Tensor<4> {
    Tensor::from_data(TensorData::new(values, [1, n, rows, cols]), device)
}
