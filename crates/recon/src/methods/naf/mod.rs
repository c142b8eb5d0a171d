//! NAF (neural attenuation fields, Zha et al. 2022) as the paper's baseline runs it: one field
//! per channel, fitted to that channel's line integrals alone.
//!
//! Per iteration: one training view (views in a fresh random order every epoch), `rays_per_batch`
//! of its rays, `samples_per_ray` stratified samples along each ray's chord through the volume box
//! ([`rays`]); the predicted line integral is `Σ_k μ(x_k)·δ` with `μ = sigmoid(field) · μ_max`
//! (mm⁻¹, [`NafConfig::attenuation_range`]); the loss is the mean squared error against the
//! measured line integrals; Adam with a step-decayed rate. The volume is the field at the voxel
//! centres. The field itself is `prism-field`'s hash-grid encoder and MLP.

pub mod config;
pub mod rays;
pub mod resume;
pub(crate) mod run;

pub use config::{NafConfig, NafMethod, StepDecay};
pub use resume::NafCheckpoints;

use crate::evaluate::CurveScoring;
use crate::init::{density_scale, fdk_of};
use crate::record::log::{LogRecord, LossTerms, RunLog};
use crate::{Error, Result};
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use ndarray::{Array3, ArrayView3};
use prism_domain::geometry::Geometry;
use prism_domain::observe::Observer;
use prism_field::NeuralField;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rays::{ChannelRays, voxel_centres};
use resume::{FieldProgress, LoopState};

/// Voxels per evaluation batch.
const EVAL_CHUNK: usize = 1 << 16;

/// One channel to fit.
pub struct ChannelTask<'a> {
    /// The channel's label (log and progress).
    pub label: &'a str,
    /// 0-based channel index (seeds differ per channel).
    pub index: usize,
    /// All projections of the scan `[view][row][col]`, and the channel's training views.
    pub projections: ArrayView3<'a, f32>,
    pub views: &'a [usize],
    /// The reference volume (mm⁻¹), for the log's PSNR, and how the log scores against it.
    pub reference: Option<ArrayView3<'a, f32>>,
    pub scoring: &'a CurveScoring,
}

/// A fit that saves its state: where, the volumes of the channels fitted before this one (they
/// go into every checkpoint), and the saved state of this channel to continue from.
pub struct Checkpointed<'r, 'a> {
    pub checkpoints: &'r mut NafCheckpoints<'a>,
    pub finished: &'r [Array3<f32>],
    pub start: Option<FieldProgress>,
}

/// Fit a field to one channel; its volume (mm⁻¹, `[z][y][x]` on the scan's grid). With
/// `checkpointed`, the fit saves its state as [`resume`] describes, and ends with
/// [`Error::Interrupted`] when asked to stop.
pub fn fit_channel(
    config: &NafConfig,
    geometry: &Geometry,
    task: &ChannelTask,
    device: &Device,
    log: &mut RunLog,
    observer: &dyn Observer,
    mut checkpointed: Option<Checkpointed>,
) -> Result<Array3<f32>> {
    config.validate()?;
    let rays = ChannelRays::new(geometry, task.projections, task.views);
    if rays.is_empty() {
        return Err(Error::invalid(
            "geometry",
            "no detector ray of the training views crosses the volume box",
        ));
    }
    let unit = density_scale(fdk_of(geometry, task.projections, task.views)?.view())?;
    let mu_max = (config.attenuation_range * unit) as f32;
    let train_device = device.clone().autodiff();
    let seed = config.seed.wrapping_add(task.index as u64);
    let mut field = config.field.init(seed, &train_device)?;
    let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
    let rng_seed = seed ^ 0x6e61_665f_7261_7973;
    let mut rng = ChaCha8Rng::seed_from_u64(rng_seed);
    let mut order: Vec<usize> = Vec::new();
    let (s, nv) = (config.samples_per_ray, rays.views.len());
    let (mut loss_sum, mut loss_n) = (0.0f64, 0usize);
    let mut first = 0;
    if let Some(c) = checkpointed.as_mut()
        && let Some(saved) = c.start.take()
    {
        let file = c.checkpoints.file().path().to_path_buf();
        if saved.state.channel != task.index || saved.state.label != task.label {
            return Err(Error::field(
                &file,
                "metadata.current",
                format!(
                    "the checkpoint continues channel `{}`, this run's is `{}`",
                    saved.state.label, task.label
                ),
            ));
        }
        saved.state.check(config.iterations, nv, &file)?;
        saved.restore(&mut field, &mut optim, &file)?;
        let st = saved.state;
        rng = st.rng(rng_seed, &file)?;
        (order, loss_sum, loss_n, first) = (st.order, st.loss_sum, st.loss_n, st.iteration);
    }
    // The volume scored at the last iteration is the result (no second evaluation).
    let mut last = None;
    observer.phase(&format!("naf {}", task.label), config.iterations as u64);
    if first > 0 {
        observer.progress(first as u64, "");
    }
    for it in first..config.iterations {
        if it % nv == 0 {
            order = (0..nv).collect();
            order.shuffle(&mut rng);
        }
        let b = rays.batch(order[it % nv], config.rays_per_batch, s, &mut rng);
        let n = b.rays();
        if n == 0 {
            continue;
        }
        let points = Tensor::<2>::from_data(TensorData::new(b.points, [n * s, 3]), &train_device);
        let steps = Tensor::<2>::from_data(TensorData::new(b.steps, [n, 1]), &train_device);
        let values = Tensor::<1>::from_data(TensorData::new(b.values, [n]), &train_device);
        let mu = field.forward(points)?;
        let pred = (mu.reshape([n, s]) * steps.mul_scalar(mu_max))
            .sum_dim(1)
            .reshape([n]);
        let loss = (pred - values).powi_scalar(2).mean();
        let value = loss.clone().into_scalar::<f32>() as f64;
        if !value.is_finite() {
            let saved = checkpointed
                .as_ref()
                .map(|c| c.checkpoints.last_written())
                .unwrap_or_default();
            return Err(Error::Diverged {
                stage: format!("naf {}", task.label),
                iter: it + 1,
                detail: format!("the loss is {value}{saved}"),
            });
        }
        loss_sum += value;
        loss_n += 1;
        let grads = GradientsParams::from_grads(loss.backward(), &field);
        field = optim.step(config.lr.at(it), field, grads);
        let done = it + 1;
        observer.progress(done as u64, &format!("loss {value:.3e}"));
        if done % config.eval_every == 0 || done == config.iterations {
            let scores = match task.reference {
                Some(r) => {
                    let vol = log.evaluating(|| volume(&field, geometry, mu_max, device))?;
                    let (p, q) = log.evaluating(|| task.scoring.score(vol.view(), r))?;
                    if done == config.iterations {
                        last = Some(vol);
                    }
                    (Some(p), Some(q))
                }
                None => (None, None),
            };
            log.write(&LogRecord {
                stage: "naf".into(),
                channel: task.label.to_string(),
                iter: done,
                wall_s: log.wall_s(),
                train_s: log.train_s(),
                loss: LossTerms {
                    total: loss_sum / loss_n.max(1) as f64,
                    ..Default::default()
                },
                n_gaussians: None,
                psnr: scores.0,
                ssim: scores.1,
            })?;
            (loss_sum, loss_n) = (0.0, 0);
        }
        if let Some(c) = &mut checkpointed {
            let stop = c.checkpoints.file().stop_requested();
            if stop || c.checkpoints.file().due(done) {
                let state = LoopState {
                    channel: task.index,
                    label: task.label.to_string(),
                    iteration: done,
                    rng_word_pos: rng.get_word_pos().to_string(),
                    order: order.clone(),
                    loss_sum,
                    loss_n,
                };
                let saved = log.saved();
                // Writing a checkpoint is not training time.
                log.evaluating(|| {
                    let progress = FieldProgress::of(&field, &optim, state)?;
                    c.checkpoints.save(c.finished, &progress, &saved)
                })?;
            }
            if stop {
                return Err(Error::Interrupted {
                    stage: format!("naf {}", task.label),
                    iter: done,
                    checkpoint: c.checkpoints.file().path().to_path_buf(),
                });
            }
        }
    }
    match last {
        Some(vol) => Ok(vol),
        None => volume(&field, geometry, mu_max, device),
    }
}

/// The field at every voxel centre of the scan's grid, × `mu_max` (mm⁻¹, `[z][y][x]`).
pub fn volume(
    field: &NeuralField,
    geometry: &Geometry,
    mu_max: f32,
    device: &Device,
) -> Result<Array3<f32>> {
    let field = field.valid();
    let grid = &geometry.volume;
    let mut out = Vec::with_capacity(grid.len());
    let mut start = 0;
    while start < grid.len() {
        let end = (start + EVAL_CHUNK).min(grid.len());
        let pts = voxel_centres(grid, start..end);
        let t = Tensor::<2>::from_data(TensorData::new(pts, [end - start, 3]), device);
        let mu = field
            .forward(t)?
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| Error::invalid("naf", format!("reading the field: {e:?}")))?;
        out.extend(mu.into_iter().map(|m| m * mu_max));
        start = end;
    }
    Array3::from_shape_vec(grid.shape_zyx(), out)
        .map_err(|e| Error::invalid("naf", format!("volume shape: {e}")))
}
