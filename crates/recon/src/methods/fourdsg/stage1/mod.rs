//! 4D-SG stage 1: one set of Gaussians, the geometry shared by every channel, and its
//! checkpoint ([`checkpoint`]) from which the spectral stage can start in another run.
//!
//! What it fits (`structural:`): a structural projection at each view (the mean over the
//! channels, or a measured full-spectrum projection), or, jointly, every measured projection of
//! every channel, each formed from per-Gaussian basis densities by the physics
//! ([`crate::gaussians::config::JointConfig`]), which end as their channel mean. The joint fit is what lets channels measured at
//! different angles (interleaved acquisitions) share one geometry: it sees the union of their
//! angles. `auto` takes the measured projection when the scene has one, the mean when every
//! training view has every channel, and the joint fit otherwise.

pub mod checkpoint;

use super::config::{FourDsgConfig, StructuralSource};
use crate::device::upload;
use crate::evaluate::CurveScoring;
use crate::gaussians::train::Evaluator;
use crate::gaussians::train::data::{Measured, image};
use crate::gaussians::train::{ChannelMap, Journal, Stage, Supervision};
use crate::gaussians::{GaussianModel, World};
use crate::init::initial_model;
use crate::methods::fourdsg::heads::BasisHead;
use crate::{Error, Result};
use burn::tensor::Device;
use ndarray::{Array3, Axis, s};
use prism_domain::decompose::channel_specs;
use prism_domain::geometry::Geometry;
use prism_domain::observe::Level;
use prism_domain::scene::Scene;

/// Stage 1's result: the shared geometry (with the common raw density) and its world.
#[derive(Clone)]
pub struct SharedGeometry {
    pub model: GaussianModel,
    pub world: World,
    /// The views stage 1 fitted.
    pub views: Vec<usize>,
}

/// What stage 1 fits: per view (`views[i]`) the supervised images `images[i]` (`[n][rows][cols]`
/// line integrals) of the channels `columns[i]` (None: every column), among `total` columns;
/// `start[i]` the one image (`[rows][cols]`) whose FDK the Gaussians start from.
pub struct Targets {
    pub source: StructuralSource,
    pub views: Vec<usize>,
    pub images: Vec<Vec<f32>>,
    pub columns: Vec<Option<Vec<usize>>>,
    pub total: usize,
    pub start: Vec<Vec<f32>>,
}

/// The source `auto` stands for in `scene`, or `source` itself.
pub fn resolve(source: StructuralSource, scene: &Scene) -> StructuralSource {
    if source != StructuralSource::Auto {
        return source;
    }
    let m = scene.n_channels();
    if scene.structural.is_some() {
        StructuralSource::Provided
    } else if scene
        .train_views()
        .iter()
        .all(|&v| (0..m).all(|c| scene.availability[[v, c]]))
    {
        StructuralSource::Mean
    } else {
        StructuralSource::Joint
    }
}

/// Stage 1's targets in `scene` (see [`Targets`]).
pub fn targets(config: &FourDsgConfig, scene: &Scene) -> Result<Targets> {
    let source = resolve(config.spectral.structural, scene);
    let m = scene.n_channels();
    let single = |views: Vec<usize>, images: Vec<Vec<f32>>| Targets {
        source,
        columns: vec![None; views.len()],
        views,
        start: images.clone(),
        images,
        total: 1,
    };
    match source {
        StructuralSource::Provided => {
            let Some(p) = scene.structural.as_ref() else {
                return Err(Error::invalid(
                    "structural",
                    "`provided` needs a scene with a measured full-spectrum projection",
                ));
            };
            let views = scene.train_views().to_vec();
            let images = views.iter().map(|&v| image(p.view(), v)).collect();
            Ok(single(views, images))
        }
        StructuralSource::Mean | StructuralSource::Auto => {
            let views: Vec<usize> = scene
                .train_views()
                .iter()
                .copied()
                .filter(|&v| (0..m).all(|c| scene.availability[[v, c]]))
                .collect();
            if views.is_empty() {
                return Err(Error::invalid(
                    "availability",
                    "no training view has every channel, so no mean structural projection \
                     exists; use `structural: joint` (or `auto`), or provide a measured one \
                     (scene `structural`)",
                ));
            }
            let images = views
                .iter()
                .map(|&v| {
                    let mean = scene
                        .projections
                        .slice(s![.., v, .., ..])
                        .mean_axis(Axis(0))
                        .expect("at least one channel");
                    mean.iter().copied().collect()
                })
                .collect();
            Ok(single(views, images))
        }
        StructuralSource::Joint => joint_targets(scene),
    }
}

/// Every training view with a measured channel, each supervising its channels; the FDK start
/// at each view is the mean of its channels, each divided by its gain ([`Scene::channel_ratios`]: the
/// channel's mean line integral over the channels').
fn joint_targets(scene: &Scene) -> Result<Targets> {
    let measured = Measured::of(scene);
    if measured.views.is_empty() {
        return Err(Error::invalid(
            "availability",
            "no training view has a measured channel",
        ));
    }
    let gains = scene.channel_ratios(&measured.views);
    let pixels = scene.geometry.detector.rows * scene.geometry.detector.cols;
    let start = measured
        .views
        .iter()
        .zip(&measured.images)
        .map(|(&v, img)| {
            let avail = scene.available_channels(v);
            let mut common = vec![0.0f64; pixels];
            for (&c, channel) in avail.iter().zip(img.chunks(pixels)) {
                let w = 1.0 / (gains[c] * avail.len() as f64);
                common
                    .iter_mut()
                    .zip(channel)
                    .for_each(|(a, &p)| *a += p as f64 * w);
            }
            common.into_iter().map(|x| x as f32).collect()
        })
        .collect();
    Ok(Targets {
        source: StructuralSource::Joint,
        views: measured.views,
        images: measured.images,
        columns: measured.columns,
        total: scene.n_channels(),
        start,
    })
}

impl Targets {
    /// The start images in a `[view][row][col]` stack of `geometry`'s views (zero elsewhere), for
    /// the FDK the Gaussians start from.
    pub fn start_stack(&self, geometry: &Geometry) -> Array3<f32> {
        let mut stack = Array3::<f32>::zeros((
            geometry.views(),
            geometry.detector.rows,
            geometry.detector.cols,
        ));
        for (v, img) in self.views.iter().zip(&self.start) {
            stack
                .index_axis_mut(Axis(0), *v)
                .iter_mut()
                .zip(img)
                .for_each(|(a, b)| *a = *b);
        }
        stack
    }
}

/// Train the shared geometry and common density of `scene` (its observed channels) on stage 1's
/// [`targets`], initialised from the FDK of their start images; its curve scored as `scoring`
/// says.
pub fn train_shared_geometry(
    config: &FourDsgConfig,
    scene: &Scene,
    scoring: &CurveScoring,
    device: &Device,
    journal: &mut Journal,
) -> Result<SharedGeometry> {
    let geometry = &scene.geometry;
    let t = targets(config, scene)?;
    let stack = t.start_stack(geometry);
    let (mut model, world) =
        initial_model(&config.geometry, geometry, stack.view(), &t.views, device)?;
    let sup = Supervision::new(
        geometry, &world, &t.views, t.images, t.columns, t.total, device,
    );
    let head = if t.source == StructuralSource::Joint {
        let (specs, exact) = channel_specs(scene)?;
        if !exact {
            journal.observer.note(
                Level::Warning,
                "the scene does not record its channels' spectra: the joint stage 1 assumes the \
                 default filtration for tube-voltage and mixed channels",
            );
        }
        let h = BasisHead::new(
            &config.spectral.joint.basis(),
            "joint",
            &specs,
            &world,
            &device.clone().autodiff(),
        )?;
        let start = h.initial_raw(&model.to_host().densities);
        model.set_densities(upload(start, h.basis().materials().len(), device));
        Some(h)
    } else {
        None
    };
    // The joint fit is scored per channel, a structural one against the channels' mean.
    let eval = scene.references.as_ref().map(|r| Evaluator {
        scoring: scoring.clone(),
        grid: geometry.volume.clone(),
        world,
        references: match head {
            Some(_) => r.outer_iter().map(|c| c.to_owned()).collect(),
            None => vec![r.mean_axis(Axis(0)).expect("at least one channel")],
        },
    });
    let (channel, map) = match &head {
        Some(h) => ("joint", ChannelMap::Mix(h)),
        None => ("structural", ChannelMap::Direct),
    };
    let stage = Stage {
        map,
        ..Stage::geometry(
            &config.geometry,
            "geometry",
            channel,
            &geometry.volume,
            &world,
        )
    };
    journal.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
    if let Some(h) = &head {
        model.set_densities(h.common_raw(&model));
    }
    Ok(SharedGeometry {
        model,
        world,
        views: t.views,
    })
}

#[cfg(test)]
mod tests;
