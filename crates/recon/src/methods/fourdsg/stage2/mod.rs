//! 4D-SG stage 2, the spectral stage, on a trained shared geometry ([`crate::methods::fourdsg::stage1`]): the curve
//! model (GSC-Net, or the MLP ablation) predicts every Gaussian's raw density curve over the
//! observed channels, `u⁽ᵐ⁾ = u⁽ᶜ⁾ + Δu⁽ᵐ⁾` with `Δu = b + net(û, τ)` (method `4dsg`); or, without
//! a curve model, per-channel densities are fitted directly on the fixed geometry (method
//! `4dsg-stage1`, the "no curve model" ablation).
//!
//! û is the conditioned common raw density (`condition_on_stage1`: centred on the median of the
//! stage-1 raw densities, scaled by half their 10–90 % range) and b a learnable per-channel
//! baseline started from the channels' mean attenuation ratios, so stage 2 does not start with
//! every channel at the channel-mean density.
//!
//! With `stage2.residual` each Gaussian also carries a free raw-density residual per channel
//! (density columns 1..=M, started at zero), added to the curve and held near zero by an L2
//! penalty: a channel may then depart from the one function of u⁽ᶜ⁾ the network gives every
//! Gaussian, where its own projections say so.
//!
//! With `stage2.basis` the spectral head is the basis-material head instead ([`crate::methods::fourdsg::heads::basis`]): the
//! Gaussians carry one density per basis material and the channels are formed by the physics.

pub mod config;

use super::config::{FourDsgConfig, FourDsgMethod};
use crate::device::upload;
use crate::evaluate::CurveScoring;
use crate::gaussians::config::GeometryConfig;
use crate::gaussians::finish::{SharedModel, Trained};
use crate::gaussians::host::{inverse_softplus, softplus};
use crate::gaussians::train::Evaluator;
use crate::gaussians::train::data::Measured;
use crate::gaussians::train::{ChannelMap, ChannelMix, DensityNet, Journal, Stage, Supervision};
use crate::gaussians::{GaussianModel, Learnable, World};
use crate::methods::fourdsg::heads::{BasisHead, CurveFit};
use crate::methods::fourdsg::stage1::SharedGeometry;
use crate::{Error, Result};
use burn::optim::AdamConfig;
use burn::tensor::{Device, Tensor};
use config::Stage2Config;
use ndarray::Axis;
use prism_domain::decompose::channel_specs;
use prism_domain::geometry::VolumeGrid;
use prism_domain::observe::Level;
use prism_domain::scene::Scene;
use prism_gscnet::SpectralGrid;

/// The spectral stage's result: the model (geometry and, with a curve model, the common raw
/// density; with the basis head, the raw basis densities `[K, B]`), its raw densities per observed
/// channel `[K, M]` and, with the basis head, the head.
pub struct Spectral {
    pub model: GaussianModel,
    pub raw: Tensor<2>,
    pub world: World,
    pub basis: Option<BasisHead>,
}

impl Spectral {
    /// The trained model as the run's finish renders it (the basis head is saved apart).
    pub(crate) fn trained(self) -> Trained {
        Trained::Shared(Box::new(SharedModel {
            model: self.model,
            raw: self.raw,
            world: self.world,
        }))
    }
}

/// Train the spectral stage of `config` on `scene` (its observed channels) from `shared`; its
/// curve scored as `scoring` says.
pub fn train_spectral(
    config: &FourDsgConfig,
    scene: &Scene,
    scoring: &CurveScoring,
    shared: SharedGeometry,
    device: &Device,
    journal: &mut Journal,
) -> Result<Spectral> {
    let geometry = &scene.geometry;
    let m = scene.n_channels();
    let SharedGeometry {
        mut model,
        world,
        views: sviews,
    } = shared;

    let measured = Measured::of(scene);
    let sup = Supervision::new(
        geometry,
        &world,
        &measured.views,
        measured.images,
        measured.columns,
        m,
        device,
    );
    let eval = scene.references.as_ref().map(|r| Evaluator {
        scoring: scoring.clone(),
        grid: geometry.volume.clone(),
        world,
        references: (0..m)
            .map(|c| r.index_axis(Axis(0), c).to_owned())
            .collect(),
    });
    let ratios = scene.channel_ratios(&sviews);
    let labels: Vec<&str> = scene.channels.iter().map(|c| c.label.as_str()).collect();
    let tv_weights = config.geometry.loss.channel_tv_weights(&labels)?;
    let mut head = None;
    let raw = match (config.method, &config.spectral.stage2.basis) {
        (FourDsgMethod::Full, Some(cfg)) => {
            let loss = &config.geometry.loss;
            for (set, field) in [
                (!loss.tv_channel_weight.is_empty(), "loss.tv_channel_weight"),
                (loss.tv_guide.is_some(), "loss.tv_guide"),
            ] {
                if set {
                    return Err(Error::invalid(
                        field,
                        "the basis head's TV is over its basis materials, not the channels",
                    ));
                }
            }
            let (specs, exact) = channel_specs(scene)?;
            if !exact {
                journal.observer.note(
                    Level::Warning,
                    "the scene does not record its channels' spectra: the basis head assumes the \
                     default filtration for tube-voltage and mixed channels",
                );
            }
            let h = BasisHead::new(cfg, "stage2", &specs, &world, &device.clone().autodiff())?;
            let start = h.initial_raw(&model.to_host().densities);
            model.set_densities(upload(start, cfg.materials.len(), device));
            let stage = Stage {
                map: ChannelMap::Mix(&h),
                ..spectral_stage(
                    &config.geometry,
                    &config.spectral.stage2,
                    "basis",
                    &geometry.volume,
                    &world,
                    Vec::new(),
                )
            };
            journal.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
            let raw = h.channel_raw(&model);
            head = Some(h);
            raw
        }
        (FourDsgMethod::Full, None) if m >= 2 => {
            let s2 = &config.spectral.stage2;
            let tau: Vec<f32> = scene.channels.iter().map(|c| c.tau as f32).collect();
            let grid = SpectralGrid::new(tau)?;
            let ad = device.clone().autodiff();
            let mut net = s2.curve_model.init(&grid, &ad, config.geometry.seed)?;
            let u = sorted_finite(model.to_host().densities);
            net.set_baseline(&spectral_baseline(&u, &ratios))?;
            if s2.condition_on_stage1 {
                let (lo, mid, hi) = (quantile(&u, 0.1), quantile(&u, 0.5), quantile(&u, 0.9));
                net.set_density_conditioning(mid, ((hi - lo) / 2.0).max(0.1))?;
            }
            let residual = s2.residual.as_ref().map(|r| r.weight);
            if residual.is_some() {
                model.append_density_columns(m);
            }
            let mut fit = CurveFit {
                net,
                optim: AdamConfig::new().init(),
                tau: grid.to_tensor(&ad),
                lambda_curve: s2.lambda_curve,
                lr: s2.lr_network,
                residual,
            };
            let stage = spectral_stage(
                &config.geometry,
                s2,
                s2.curve_model.kind.name(),
                &geometry.volume,
                &world,
                tv_weights.clone(),
            );
            journal.train(
                &mut model,
                &sup,
                eval.as_ref(),
                &stage,
                Some(&mut fit as &mut dyn DensityNet),
            )?;
            fit.raw_densities(&model)?
        }
        _ => {
            if config.method == FourDsgMethod::Full {
                journal.observer.note(
                    Level::Info,
                    "one observed channel: no spectral axis, stage 2 is skipped and the stage-1 \
                     densities are the result",
                );
            }
            // Per-channel densities fitted directly on the fixed geometry, initialised from the
            // common density scaled by each channel's mean line integral relative to the
            // channels' average.
            let common: Vec<f32> = model.to_host().densities;
            let raw: Vec<f32> = common
                .iter()
                .flat_map(|&u| {
                    let a = softplus(u as f64);
                    ratios.iter().map(move |r| inverse_softplus(a * r) as f32)
                })
                .collect();
            model.set_densities(upload(raw, m, device));
            let stage = Stage {
                iterations: config.spectral.density_iterations,
                learn: Learnable::DENSITY,
                ..spectral_stage(
                    &config.geometry,
                    &config.spectral.stage2,
                    "densities",
                    &geometry.volume,
                    &world,
                    tv_weights.clone(),
                )
            };
            journal.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
            model.densities.value.clone()
        }
    };
    Ok(Spectral {
        model,
        raw,
        world,
        basis: head,
    })
}

/// The spectral stage of the geometry stage `config` named `name`: `stage2`'s iterations and
/// freezing, no densification, its own seed, every channel fitted (their TV weighted as
/// `loss.tv_channel_weight` says, for `tv_weights`, the channels' weights).
fn spectral_stage<'a>(
    config: &'a GeometryConfig,
    stage2: &Stage2Config,
    name: &'a str,
    grid: &'a VolumeGrid,
    world: &'a World,
    tv_weights: Vec<f64>,
) -> Stage<'a> {
    Stage {
        iterations: stage2.iterations,
        tv_weights,
        learn: stage2.freeze.learnable(),
        densify: None,
        seed: config.seed.wrapping_add(1),
        ..Stage::geometry(config, name, "all", grid, world)
    }
}

/// The finite values of `v`, ascending.
fn sorted_finite(mut v: Vec<f32>) -> Vec<f32> {
    v.retain(|x| x.is_finite());
    v.sort_by(f32::total_cmp);
    v
}

/// The `q`-quantile (nearest rank) of ascending `sorted` (0 when empty).
fn quantile(sorted: &[f32], q: f64) -> f32 {
    let i = ((sorted.len().saturating_sub(1)) as f64 * q).round() as usize;
    sorted.get(i).copied().unwrap_or(0.0)
}

/// Raw-density offsets b [M] that turn the structural densities into each channel's, for the
/// curve model's baseline: softplus(ū + b_m) = r_m·softplus(ū) at the median ū of the ascending
/// raw densities `sorted` (`ratios` from [`Scene::channel_ratios`]).
fn spectral_baseline(sorted: &[f32], ratios: &[f64]) -> Vec<f32> {
    let u = quantile(sorted, 0.5) as f64;
    let a = softplus(u);
    ratios
        .iter()
        .map(|&r| (inverse_softplus(a * r) - u) as f32)
        .collect()
}
