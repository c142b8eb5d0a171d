//! The run pipeline: one entry point, [`run`], for every method. It checks the scene, runs the
//! method ([`crate::methods`]) into a [`RunDir`], scores the volumes ([`crate::evaluate`]) and
//! publishes the directory as a whole. [`footprint`] estimates a run's peak memory.

pub(crate) mod footprint;
mod gaussian;

pub use footprint::{footprint, run_footprint};

use gaussian::Gaussian;

use crate::evaluate::Metrics;
use crate::methods::{classic, naf};
use crate::record::RunDir;
use crate::setup::RunOptions;
use crate::{MethodConfig, Result};
use prism_domain::scene::Scene;
use std::path::PathBuf;

/// Reconstruct `scene` with `config` into `dir` and publish it.
pub fn run(
    config: &MethodConfig,
    scene: &Scene,
    mut dir: RunDir,
    options: &RunOptions,
) -> Result<Outcome> {
    options.check(config)?;
    // An evaluation that cannot run fails now, not after the reconstruction.
    options.evaluation.check(scene)?;
    dir.write_text(RunDir::CONFIG, &config.resolved_yaml()?)?;
    let metrics = match config {
        MethodConfig::Classic(c) => classic::run::run(c, scene, &mut dir, options)?,
        MethodConfig::Naf(c) => naf::run::run(c, scene, &mut dir, options)?,
        MethodConfig::R2gs(c) => gaussian::run(Gaussian::R2gs(c), scene, &mut dir, options)?,
        MethodConfig::FourDsg(c) => gaussian::run(Gaussian::FourDsg(c), scene, &mut dir, options)?,
    };
    if let Some(m) = &metrics {
        dir.write_json(RunDir::METRICS, m)?;
    }
    let dir = dir.publish()?;
    // The checkpoint served its purpose: the run is complete and published.
    if let Some(c) = &options.checkpoint
        && c.path.is_file()
    {
        std::fs::remove_file(&c.path).map_err(|e| crate::Error::io(&c.path, e))?;
    }
    Ok(Outcome { dir, metrics })
}

/// A finished run.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// Where the run directory was published.
    pub dir: PathBuf,
    /// The scores (`metrics.json`), when the scene has reference volumes.
    pub metrics: Option<Metrics>,
}

#[cfg(test)]
pub(crate) mod gaussian_tests;
#[cfg(test)]
mod resume_tests;
#[cfg(test)]
pub(crate) mod tests;
