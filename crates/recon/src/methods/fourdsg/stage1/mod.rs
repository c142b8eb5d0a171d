//! 4D-SG stage 1: one set of Gaussians, the geometry shared by every channel, trained on the
//! structural projections (the mean over the channels at each view, or a measured
//! full-spectrum projection), and its checkpoint ([`checkpoint`]) from which the spectral stage
//! can start in another run.

pub mod checkpoint;

use crate::gaussians::config::StructuralSource;
use crate::gaussians::train::Evaluator;
use crate::gaussians::train::data::image;
use crate::gaussians::train::{Journal, Stage, Supervision};
use crate::gaussians::{GaussianConfig, GaussianModel, World};
use crate::init::initial_model;
use crate::{Error, Result};
use burn::tensor::Device;
use ndarray::{Array3, Axis, s};
use prism_domain::scene::Scene;

/// Stage 1's result: the shared geometry (with the common raw density) and its world.
#[derive(Clone)]
pub struct SharedGeometry {
    pub model: GaussianModel,
    pub world: World,
    /// The views of the structural projections.
    pub views: Vec<usize>,
}

/// The structural projections of `scene`: `(views, images)`, each image `[rows][cols]`.
pub fn structural(config: &GaussianConfig, scene: &Scene) -> Result<(Vec<usize>, Vec<Vec<f32>>)> {
    let provided = scene.structural.as_ref();
    match (config.structural, provided) {
        (StructuralSource::Provided, None) => Err(Error::invalid(
            "structural",
            "`provided` needs a scene with a measured full-spectrum projection",
        )),
        (StructuralSource::Provided | StructuralSource::Auto, Some(p)) => {
            let views = scene.train_views().to_vec();
            let images = views.iter().map(|&v| image(p.view(), v)).collect();
            Ok((views, images))
        }
        _ => {
            let m = scene.n_channels();
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
                     exists; provide a measured one (scene `structural`)",
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
            Ok((views, images))
        }
    }
}

/// Train the shared geometry and common density of `scene` (its observed channels) from the
/// structural projections, initialised from their FDK.
pub fn train_shared_geometry(
    config: &GaussianConfig,
    scene: &Scene,
    device: &Device,
    journal: &mut Journal,
) -> Result<SharedGeometry> {
    let geometry = &scene.geometry;
    let (sviews, simages) = structural(config, scene)?;
    let mut stack = Array3::<f32>::zeros((
        geometry.views(),
        geometry.detector.rows,
        geometry.detector.cols,
    ));
    for (v, img) in sviews.iter().zip(&simages) {
        stack
            .index_axis_mut(Axis(0), *v)
            .iter_mut()
            .zip(img)
            .for_each(|(a, b)| *a = *b);
    }
    let (mut model, world) = initial_model(config, geometry, stack.view(), &sviews, device)?;
    let sup = Supervision::single(geometry, &world, &sviews, simages, device);
    let eval = scene.references.as_ref().map(|r| Evaluator {
        grid: geometry.volume.clone(),
        world,
        references: vec![r.mean_axis(Axis(0)).expect("at least one channel")],
    });
    let stage = Stage::geometry(config, "geometry", "structural", &geometry.volume, &world);
    journal.train(&mut model, &sup, eval.as_ref(), &stage, None)?;
    Ok(SharedGeometry {
        model,
        world,
        views: sviews,
    })
}
