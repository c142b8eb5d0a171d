//! What a training stage is told: its iterations, which groups learn, the schedule's rates, the
//! loss weights, densification, evaluation and seed.

use super::head::ChannelMix;
use crate::Result;
use crate::gaussians::config::{
    DensifyConfig, GeometryConfig, LearningRates, LossConfig, ViewsPerStep,
};
use crate::gaussians::{Learnable, World};
use prism_domain::geometry::VolumeGrid;
use prism_render::ProjectOptions;

/// The settings of one training stage.
pub struct Stage<'a> {
    /// Name in the log (`r2gs`, `geometry`, and 4D-SG's `densities`, `basis`, `gscnet`, `mlp`).
    pub name: &'a str,
    /// What is fitted, for the log (`structural`, a channel label, `all`).
    pub channel: &'a str,
    pub iterations: usize,
    pub learn: Learnable,
    pub lr: &'a LearningRates,
    pub loss: &'a LossConfig,
    /// Each rendered channel's TV weight as a multiple of `loss.lambda_tv`, in the model's
    /// channel order (`loss.tv_channel_weight` resolved against the channels' labels); empty:
    /// every channel weighs 1.
    pub tv_weights: Vec<f64>,
    /// How many training views a step fits.
    pub views_per_step: ViewsPerStep,
    /// How the training views are rendered.
    pub projection: ProjectOptions,
    pub densify: Option<&'a DensifyConfig>,
    /// Evaluate (voxelize and score) every this many iterations and at the end; 0: only at the end.
    pub eval_every: usize,
    /// Grid of the TV patch's voxel size and of the volume box (millimetres).
    pub grid: &'a VolumeGrid,
    pub world: &'a World,
    pub seed: u64,
    /// How the rendered density columns become the supervised channels.
    pub map: ChannelMap<'a>,
}

/// How a stage's rendered density columns become the channels it supervises.
#[derive(Clone, Copy, Default)]
pub enum ChannelMap<'a> {
    /// Each column is a channel (or, with a density network, the network's channels).
    #[default]
    Direct,
    /// A channel mix forms the channels from the columns' projections (4D-SG's basis-material
    /// head: the columns are basis materials).
    Mix(&'a dyn ChannelMix),
}

impl ChannelMap<'_> {
    /// `(channels rendered, density columns the model needs)`, or None for [`ChannelMap::Direct`].
    pub fn columns(&self) -> Option<(usize, usize)> {
        match self {
            ChannelMap::Direct => None,
            ChannelMap::Mix(h) => Some(h.shape()),
        }
    }

    /// The channels' line integrals `[V, M, rows, cols]` from the rendered columns.
    pub fn project(&self, rendered: burn::tensor::Tensor<4>) -> burn::tensor::Tensor<4> {
        match self {
            ChannelMap::Direct => rendered,
            ChannelMap::Mix(h) => h.project(rendered),
        }
    }
}

impl<'a> Stage<'a> {
    /// A geometry stage of `config` (all groups learnable, the config's schedule and
    /// densification) named `name`, fitting `channel`, on `grid` (millimetres) in `world`.
    pub fn geometry(
        config: &'a GeometryConfig,
        name: &'a str,
        channel: &'a str,
        grid: &'a VolumeGrid,
        world: &'a World,
    ) -> Stage<'a> {
        Stage {
            name,
            channel,
            iterations: config.iterations,
            learn: Learnable::ALL,
            lr: &config.lr,
            loss: &config.loss,
            tv_weights: Vec::new(),
            views_per_step: config.views_per_step,
            projection: config.projection.options(),
            densify: config.densify.as_ref(),
            eval_every: config.eval_every,
            grid,
            world,
            seed: config.seed,
            map: ChannelMap::Direct,
        }
    }

    pub fn validate(&self) -> Result<()> {
        self.lr.validate()?;
        self.loss.validate()?;
        if let Some(d) = self.densify {
            d.validate()?;
        }
        Ok(())
    }

    /// Densification in this stage: configured, and the positions learn.
    pub fn densification(&self) -> Option<&DensifyConfig> {
        self.densify.filter(|_| self.learn.position)
    }
}
