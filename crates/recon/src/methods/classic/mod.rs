//! The classic methods (`fdk`, `sart`, `cgls`): every channel reconstructed independently from
//! its training views by one of [`crate::algorithms`]. [`config`] holds the YAML, [`run`] the run,
//! [`bench`] the comparison with RTK (`prism bench classic`).

pub mod bench;
pub mod config;
pub(crate) mod run;

pub use config::{ClassicConfig, ClassicMethod};

use crate::algorithms::{cgls, fdk, sart};
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
    }
}
