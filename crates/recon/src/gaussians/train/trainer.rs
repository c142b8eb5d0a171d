//! One training iteration: [`Trainer::step`].
//!
//! A step draws its training views (without replacement until every view was used, then
//! reshuffled; seeded): one, or with `views_per_step: cover` one of every channel on a scan whose
//! views measure different channels ([`draw_views`]). It renders them in one projection,
//! minimises the mean over the views of `L1 + λ_dssim·(1 − SSIM)` plus `λ_tv·TV(32³ patch)`
//! (terms with weight 0 are not computed; a density network adds its regulariser, 4D-SG's
//! `λ_curve·L_curve`), and takes one Adam step of each learnable group at the rates the
//! [`StepPlan`] gives. When densification is on, the view-space gradient statistics are
//! accumulated (a step's norms summed over its views, counted once) and, when the plan says so,
//! clone/split/prune runs (after that step's Adam update; upstream skips the update at those
//! iterations). What happens when is the driver's business ([`super::train`]); the trainer only
//! does it.

use super::Timing;
use super::data::Supervision;
use super::data_term::{count_weights, image_rms, l1, weighted_l1};
use super::densify::{DensifyCounts, densify_and_prune};
use super::draw::draw_views;
use super::head::{DensityNet, common_density};
use super::loss::{SsimWindow, directional_total_variation, total_variation};
use super::settings::{ChannelMap, Stage};
use crate::gaussians::GaussianModel;
use crate::gaussians::config::{DataNorm, DataWeighting, Rates};
use crate::gaussians::model::softplus;
use crate::record::log::LossTerms;
use crate::{Error, Result};
use burn::tensor::{Tensor, TensorData};
use prism_domain::geometry::VolumeGrid;
use prism_render::{VoxelGrid, VoxelizeOptions, project, screen_grad_norm, screen_probe, voxelize};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;

/// The random stream and view order of a [`Trainer`] ([`Trainer::cursor`]).
pub struct Cursor {
    rng: ChaCha8Rng,
    order: Vec<usize>,
}

/// A trainer's own state between two steps: the position in its random stream (seeded by the
/// stage's seed), the views left in the current pass and, while densifying, the view-space
/// gradient statistics `(sum, count)` per Gaussian. With the model (and density network) it
/// continues a stage exactly.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrainerState {
    /// Word position in the ChaCha8 stream, in decimal (JSON numbers stop at 2⁵³).
    pub rng_word_pos: String,
    pub order: Vec<usize>,
    /// Stored as tensors, not in the JSON metadata.
    #[serde(skip)]
    pub stats: Option<(Vec<f32>, Vec<f32>)>,
}

/// What one step does beyond the gradient step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DensifyStep {
    /// Nothing (no densification in this stage, or past its window).
    Off,
    /// Accumulate the view-space gradient statistics.
    Accumulate,
    /// Accumulate, then clone, split and prune.
    Apply,
}

/// The schedule's orders for one step.
#[derive(Clone, Copy, Debug)]
pub struct StepPlan {
    /// 1-based iteration within the stage.
    pub iteration: usize,
    /// Learning rates of the Gaussian parameter groups.
    pub rates: Rates,
    /// Learning rate of the density network, if the stage trains one.
    pub network_lr: f64,
    pub densify: DensifyStep,
}

/// What one step did.
#[derive(Clone, Copy, Debug)]
pub struct StepStats {
    pub loss: LossTerms,
    pub timing: Timing,
    /// What densification did, when it ran.
    pub densified: Option<DensifyCounts>,
}

/// A model being trained on one stage's supervision.
pub struct Trainer<'a> {
    model: &'a mut GaussianModel,
    curve: Option<&'a mut dyn DensityNet>,
    sup: &'a Supervision,
    stage: &'a Stage<'a>,
    window: SsimWindow,
    rng: ChaCha8Rng,
    /// Views still to draw in this pass.
    order: Vec<usize>,
    /// The volume grid in normalised units (the TV patch's voxel size) and its box.
    grid: VolumeGrid,
    bbox: ([f64; 3], [f64; 3]),
    /// View-space gradient statistics, when the stage densifies.
    stats: Option<GradStats>,
    /// Pixel → NDC gradient units (R²-Gaussian's densification threshold is in NDC).
    ndc: f32,
    /// Each view's pixel weights in the L1 term, when the loss weighs them.
    weights: Option<Vec<Tensor<4>>>,
    /// Each channel's TV weight `[M, 1, 1, 1]` relative to `λ_tv`, when one differs from 1.
    tv_weights: Option<Tensor<4>>,
}

impl<'a> Trainer<'a> {
    /// A trainer of `model` (and of the density network `curve`, if any) on `sup`.
    pub fn new(
        model: &'a mut GaussianModel,
        sup: &'a Supervision,
        stage: &'a Stage<'a>,
        curve: Option<&'a mut dyn DensityNet>,
    ) -> Result<Self> {
        stage.validate()?;
        let Some(first) = sup.views.first() else {
            return Err(Error::invalid("views", "no training view to fit"));
        };
        let (columns, needs) = match (&curve, stage.map.columns()) {
            (Some(c), _) => (c.channels(), c.columns()),
            (None, Some(map)) => map,
            (None, None) => (model.channels(), model.channels()),
        };
        if columns != sup.columns || model.channels() != needs {
            return Err(Error::invalid(
                "densities",
                format!(
                    "the model renders {columns} density columns, the stage supervises {}",
                    sup.columns
                ),
            ));
        }
        if !stage.tv_weights.is_empty() && stage.tv_weights.len() != columns {
            return Err(Error::invalid(
                "loss.tv_channel_weight",
                format!(
                    "{} channel weights for a model of {columns} density columns",
                    stage.tv_weights.len()
                ),
            ));
        }
        let device = model.device();
        let tv_weights = stage.tv_weights.iter().any(|&w| w != 1.0).then(|| {
            let w: Vec<f32> = stage.tv_weights.iter().map(|&w| w as f32).collect();
            let m = w.len();
            Tensor::from_data(TensorData::new(w, [m, 1, 1, 1]), &device.clone().autodiff())
        });
        let grid = stage.world.volume(stage.grid);
        let stats = stage
            .densification()
            .map(|_| GradStats::new(model.len(), &device));
        let weights = match stage.loss.weighting {
            DataWeighting::None => None,
            DataWeighting::Counts => {
                Some(count_weights(sup, stage.world.projection_factor() as f32))
            }
        };
        Ok(Trainer {
            weights,
            tv_weights,
            window: SsimWindow::new(&device.autodiff()),
            rng: ChaCha8Rng::seed_from_u64(stage.seed),
            order: Vec::new(),
            bbox: grid.bounds(),
            grid,
            stats,
            ndc: (first.camera.rows + first.camera.cols) as f32 / 4.0,
            model,
            curve,
            sup,
            stage,
        })
    }

    /// The model as trained so far.
    pub fn model(&self) -> &GaussianModel {
        self.model
    }

    /// The density network, if the stage trains one.
    pub fn curve(&self) -> Option<&dyn DensityNet> {
        self.curve.as_deref()
    }

    /// Where the random stream and the view order stand (cheap: taken before every step when
    /// a run is checkpointed, to save the state before a step that diverges).
    pub fn cursor(&self) -> Cursor {
        Cursor {
            rng: self.rng.clone(),
            order: self.order.clone(),
        }
    }

    /// Put the random stream and the view order back where `cursor` found them.
    pub fn rewind(&mut self, cursor: Cursor) {
        self.rng = cursor.rng;
        self.order = cursor.order;
    }

    /// The trainer's own state between two steps (see [`TrainerState`]).
    pub fn state(&self) -> TrainerState {
        TrainerState {
            rng_word_pos: self.rng.get_word_pos().to_string(),
            order: self.order.clone(),
            stats: self.stats.as_ref().map(|s| {
                (
                    crate::device::host_values(&s.sum),
                    crate::device::host_values(&s.count),
                )
            }),
        }
    }

    /// Continue from `state` (saved by [`Trainer::state`] from a trainer of the same stage and
    /// model); `file` names it in errors.
    pub fn restore(&mut self, state: TrainerState, file: &std::path::Path) -> Result<()> {
        let bad = |field: &str, why: String| {
            Error::field(file, format!("metadata.current.trainer.{field}"), why)
        };
        let pos = crate::record::resume::word_position(
            &state.rng_word_pos,
            file,
            "metadata.current.trainer.rng_word_pos",
        )?;
        let n = self.sup.views.len();
        prism_domain::indices::distinct_below(&state.order, n)
            .map_err(|fault| bad("order", format!("training view {fault}")))?;
        let k = self.model.len();
        match (&mut self.stats, state.stats) {
            (Some(st), Some((sum, count))) if sum.len() == k && count.len() == k => {
                if let Some(v) = sum
                    .iter()
                    .chain(&count)
                    .find(|v| !(v.is_finite() && **v >= 0.0))
                {
                    return Err(bad(
                        "stats",
                        format!("densification statistic {v} is not a finite value ≥ 0"),
                    ));
                }
                let device = self.model.device();
                st.sum = crate::device::upload(sum, 1, &device).reshape([k]);
                st.count = crate::device::upload(count, 1, &device).reshape([k]);
            }
            (None, None) => {}
            (_, got) => {
                return Err(bad(
                    "stats",
                    format!(
                        "densification statistics for {} Gaussians do not fit this stage ({})",
                        got.map_or(0, |g| g.0.len()),
                        if self.stats.is_some() {
                            format!("densifying, {k} Gaussians")
                        } else {
                            "not densifying".into()
                        }
                    ),
                ));
            }
        }
        self.rng.set_word_pos(pos);
        self.order = state.order;
        Ok(())
    }

    /// One iteration (see the module docs).
    pub fn step(&mut self, plan: &StepPlan) -> Result<StepStats> {
        let (sup, stage) = (self.sup, self.stage);
        let batch = self.draw();

        let t0 = Instant::now();
        let mut act = self.model.activate(Some(stage.learn));
        let delta_u = match &self.curve {
            Some(c) => {
                let u = act.leaves[3].clone();
                let du = c.offsets(u.clone())?;
                act.gaussians.densities = softplus(common_density(u.clone()) + du.clone());
                Some((u, du))
            }
            None => None,
        };
        let probe = self
            .stats
            .as_ref()
            .map(|_| screen_probe(&act.gaussians, batch.len()));
        let cameras: Vec<_> = batch.iter().map(|&i| sup.views[i].camera).collect();
        let img = stage.map.project(project(
            &act.gaussians,
            &cameras,
            probe.as_ref(),
            &stage.projection,
        )?);
        let t1 = Instant::now();

        // The data terms of every drawn view, averaged over the views (one view: as they are).
        let mut l_1 = Vec::with_capacity(batch.len());
        let mut dssim = Vec::with_capacity(batch.len());
        for (b, &index) in batch.iter().enumerate() {
            let view = &sup.views[index];
            let mut img = match batch.len() {
                1 => img.clone(),
                _ => img.clone().narrow(0, b, 1),
            };
            if let Some(c) = &view.columns {
                img = img.select(1, c.index.clone());
            }
            let weights = self.weights.as_ref().map(|w| w[index].clone());
            l_1.push(match (stage.loss.data, weights) {
                (DataNorm::L1, Some(w)) => weighted_l1(img.clone(), view.target.clone(), w),
                (DataNorm::L1, None) => l1(img.clone(), view.target.clone()),
                (DataNorm::Rms, w) => image_rms(img.clone(), view.target.clone(), w),
            });
            if stage.loss.lambda_dssim > 0.0 {
                dssim.push(self.window.ssim(img, view.target.clone()).neg() + 1.0);
            }
        }
        let l_1 = batch_mean(l_1);
        let mut total = l_1.clone();
        let dssim = (!dssim.is_empty()).then(|| {
            let d = batch_mean(dssim);
            total = total.clone() + d.clone() * stage.loss.lambda_dssim;
            d
        });
        let tv = if stage.loss.lambda_tv > 0.0 {
            let patch = tv_patch(&self.grid, stage.loss.tv_patch, &mut self.rng);
            let v = voxelize(&act.gaussians, &patch, &VoxelizeOptions::default())?;
            let w = self.tv_weights.clone();
            // Directional TV where the model's densities are several channels (not a basis
            // head's materials).
            let channels = v.dims()[0] > 1 && matches!(stage.map, ChannelMap::Direct);
            let tv = match &stage.loss.tv_guide {
                Some(g) if channels => directional_total_variation(v, g.eta, w),
                // TV is positively homogeneous: the TV of `w_m·v_m` is `w_m` times `v_m`'s.
                _ => total_variation(match w {
                    Some(w) => v * w,
                    None => v,
                }),
            };
            total = total.clone() + tv.clone() * stage.loss.lambda_tv;
            Some(tv)
        } else {
            None
        };
        let l_curve = match (&self.curve, delta_u) {
            (Some(c), Some((u, du))) => c.regulariser(u, du)?.map(|(l, weight)| {
                total = total.clone() + l.clone() * weight;
                l
            }),
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
        let read = crate::device::host_values(&packed);
        let loss = LossTerms {
            total: read[0] as f64,
            l1: read[1] as f64,
            dssim: read[2] as f64,
            tv: read[3] as f64,
            curve: read[4] as f64,
        };
        let t3 = Instant::now();
        if !loss.total.is_finite() {
            return Err(Error::Diverged {
                stage: stage.name.to_string(),
                iter: plan.iteration,
                detail: format!("the loss is not finite ({loss:?})"),
            });
        }

        let [lm, ls, lr_, ld] = &act.leaves;
        let r = plan.rates;
        let model = &mut *self.model;
        let groups = [
            (stage.learn.position, lm, &mut model.means, r.position),
            (stage.learn.scale, ls, &mut model.scales, r.scale),
            (stage.learn.rotation, lr_, &mut model.rotations, r.rotation),
            (stage.learn.density, ld, &mut model.densities, r.density),
        ];
        for (on, leaf, param, rate) in groups {
            if on && let Some(g) = leaf.grad(&grads) {
                param.step(g, rate);
            }
        }
        let probe_grad = probe.as_ref().and_then(|p| p.grad(&grads));
        if let Some(c) = self.curve.as_deref_mut() {
            c.step(grads, plan.network_lr);
        }
        let t4 = Instant::now();

        let densified = match plan.densify {
            DensifyStep::Off => None,
            DensifyStep::Accumulate | DensifyStep::Apply => self.densify(plan, probe_grad)?,
        };
        let t5 = Instant::now();
        Ok(StepStats {
            loss,
            timing: Timing {
                render: (t1 - t0).as_secs_f64(),
                loss: (t2 - t1).as_secs_f64(),
                backward: (t3 - t2).as_secs_f64(),
                optimiser: (t4 - t3).as_secs_f64(),
                densify: (t5 - t4).as_secs_f64(),
            },
            densified,
        })
    }

    /// The training views of one step ([`draw_views`]).
    fn draw(&mut self) -> Vec<usize> {
        let views = &self.sup.views;
        draw_views(
            &mut self.order,
            &mut self.rng,
            views.len(),
            |i| views[i].columns.as_ref().map(|c| c.list.as_slice()),
            self.sup.columns,
            self.stage.views_per_step,
        )
    }

    /// Add this step's view-space gradient to the statistics and, when `plan` says so, clone,
    /// split and prune with them.
    fn densify(
        &mut self,
        plan: &StepPlan,
        probe_grad: Option<Tensor<3>>,
    ) -> Result<Option<DensifyCounts>> {
        let (Some(cfg), Some(st)) = (self.stage.densification(), self.stats.as_mut()) else {
            return Ok(None);
        };
        if let Some(g) = probe_grad {
            st.add(screen_grad_norm(&g) * self.ndc);
        }
        if plan.densify != DensifyStep::Apply {
            return Ok(None);
        }
        let host = self.model.to_host();
        let scores = st.scores();
        let (next, src, counts) = densify_and_prune(
            &host,
            &scores,
            &self.model.bounds,
            self.bbox,
            cfg,
            &mut self.rng,
        );
        self.model.remap(&next, &src);
        *st = GradStats::new(self.model.len(), &self.model.device());
        if self.model.is_empty() {
            return Err(Error::invalid(
                "densify.min_density",
                "pruning removed every Gaussian",
            ));
        }
        Ok(Some(counts))
    }
}

/// The mean of a step's per-view loss terms (a single term as it is, so one-view steps are
/// unchanged).
fn batch_mean(terms: Vec<Tensor<1>>) -> Tensor<1> {
    let n = terms.len();
    let sum = terms
        .into_iter()
        .reduce(|a, b| a + b)
        .expect("a step draws at least one view");
    match n {
        1 => sum,
        _ => sum / n as f64,
    }
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
        let s = crate::device::host_values(&self.sum);
        let c = crate::device::host_values(&self.count);
        s.iter()
            .zip(&c)
            .map(|(s, c)| if *c > 0.0 { s / c } else { 0.0 })
            .collect()
    }
}
