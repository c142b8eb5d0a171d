//! The classic methods: `fdk`, `sart` and `cgls` reconstruct every channel independently from
//! its training views by one of [`crate::algorithms`]; `tv` reconstructs every channel at once,
//! each from its own views, with a total-variation regulariser that couples them
//! ([`crate::algorithms::tv`]). [`config`] holds the YAML, [`run`] the run, [`bench`] the
//! comparison with RTK (`prism bench classic`).

pub mod bench;
pub mod config;
pub mod import;
pub(crate) mod run;

pub use config::{ClassicConfig, ClassicMethod};

use crate::algorithms::{
    ChannelData, Coupling, Directions, TvOptions, cgls, fdk, sart, tv, tv_guided,
};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3, Axis};
use prism_domain::geometry::Geometry;
use prism_domain::projector::Joseph;

/// Reconstruct one channel's volume from the listed views (`views` index the scene geometry);
/// `progress` is called after each iteration of an iterative method.
pub fn reconstruct_channel(
    config: &ClassicConfig,
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    views: &[usize],
    progress: &mut dyn FnMut(usize),
) -> Result<Array3<f32>> {
    config.validate()?;
    if views.is_empty() {
        return Err(Error::invalid("views", "the view list is empty"));
    }
    let sub = geometry.with_views(views);
    let p = projections.select(Axis(0), views);
    match config.method {
        ClassicMethod::Fdk => fdk(&sub, p.view(), config.filter),
        ClassicMethod::Sart => sart(
            &Joseph::new(&sub)?,
            p.view(),
            None,
            &config.sart_options(),
            progress,
        ),
        ClassicMethod::Cgls => cgls(
            &Joseph::new(&sub)?,
            p.view(),
            None,
            config.resolved_iterations(),
            progress,
        ),
        ClassicMethod::Tv => {
            if config.tv.guide.is_some() {
                return Err(Error::invalid(
                    "tv.guide",
                    "directional TV is guided by several channels' mean; one channel alone has \
                     no side information",
                ));
            }
            let a = Joseph::new(&sub)?;
            let start = tv_start(config, &sub, p.view())?;
            let one = ChannelData {
                projector: &a,
                projections: p.view(),
                weight: 1.0,
                start: start.as_ref().map(|v| v.view()),
            };
            let mut v = tv(&[one], &config.tv_options(), progress)?;
            Ok(v.remove(0))
        }
    }
}

/// Reconstruct every channel (`projections[c]` with every view of `geometry`, `views[c]` its
/// training views) with `method: tv`, the channels coupled by the regulariser. A channel's
/// regulariser weight is the inverse of its gain `gains[c]` (its mean training line integral
/// over the channels' mean, [`channel_ratios`]), so channels of different contrast count alike.
/// With `tv.guide`, the guide is reconstructed first (its iterations reported before the
/// channels': `progress` counts both) and the channels' TV is directional.
///
/// [`channel_ratios`]: prism_domain::scene::Scene::channel_ratios
pub fn reconstruct_jointly(
    config: &ClassicConfig,
    geometry: &Geometry,
    projections: &[ArrayView3<f32>],
    views: &[Vec<usize>],
    gains: &[f64],
    progress: &mut dyn FnMut(usize),
) -> Result<Vec<Array3<f32>>> {
    config.validate()?;
    let mut projectors = Vec::with_capacity(views.len());
    let mut data = Vec::with_capacity(views.len());
    let mut starts = Vec::with_capacity(views.len());
    for (c, (b, v)) in projections.iter().zip(views).enumerate() {
        if v.is_empty() {
            return Err(Error::invalid(
                format!("channels[{c}].views"),
                "the view list is empty",
            ));
        }
        let sub = geometry.with_views(v);
        let b = b.select(Axis(0), v);
        starts.push(tv_start(config, &sub, b.view())?);
        projectors.push(Joseph::new(&sub)?);
        data.push(b);
    }
    let channels: Vec<ChannelData> = projectors
        .iter()
        .zip(&data)
        .zip(gains)
        .zip(&starts)
        .map(|(((a, b), &g), s)| ChannelData {
            projector: a,
            projections: b.view(),
            weight: (1.0 / g) as f32,
            start: s.as_ref().map(|v| v.view()),
        })
        .collect();
    let directions = match &config.tv.guide {
        Some(g) => {
            let image = reconstruct_guide(config, g, views, &channels, progress)?;
            Some(Directions::of(image.view(), g.eta))
        }
        None => None,
    };
    let done = if directions.is_some() {
        config.resolved_iterations()
    } else {
        0
    };
    tv_guided(
        &channels,
        &config.tv_options(),
        directions.as_ref(),
        &mut |k| progress(done + k),
    )
}

/// Directional TV's guide image: channel TV (weight `guide.weight`) of the channels' mean
/// sinogram, which needs every channel measured at the same views.
fn reconstruct_guide(
    config: &ClassicConfig,
    guide: &config::Guide,
    views: &[Vec<usize>],
    channels: &[ChannelData],
    progress: &mut dyn FnMut(usize),
) -> Result<Array3<f32>> {
    if views.iter().any(|v| v != &views[0]) {
        return Err(Error::invalid(
            "tv.guide",
            "the channels are measured at different views (an interleaved scan): the guide is \
             reconstructed from their mean sinogram, which needs common views",
        ));
    }
    let mut mean = channels[0].projections.to_owned();
    for ch in &channels[1..] {
        mean += &ch.projections;
    }
    mean /= channels.len() as f32;
    let first = &channels[0];
    let start = tv_start(config, first.projector.geometry(), mean.view())?;
    let one = ChannelData {
        projector: first.projector,
        projections: mean.view(),
        weight: 1.0,
        start: start.as_ref().map(|v| v.view()),
    };
    let options = TvOptions {
        weight: guide.weight,
        coupling: Coupling::Channel,
        ..config.tv_options()
    };
    Ok(tv(&[one], &options, progress)?.remove(0))
}

/// TV's starting volume of one channel (`start: fdk`: its FDK from `projections` at `geometry`'s
/// views, clipped at 0 under `nonneg`), or `None` to start from zero.
fn tv_start(
    config: &ClassicConfig,
    geometry: &Geometry,
    projections: ArrayView3<f32>,
) -> Result<Option<Array3<f32>>> {
    if config.start != config::Start::Fdk {
        return Ok(None);
    }
    let mut v = fdk(geometry, projections, config.filter)?;
    if config.nonneg {
        v.mapv_inplace(|x| x.max(0.0));
    }
    Ok(Some(v))
}
