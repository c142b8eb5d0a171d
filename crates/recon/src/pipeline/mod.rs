//! The run pipeline: one entry point, [`run`], for every method. It checks the scene, runs the
//! method's stages into a [`RunDir`], scores the volumes ([`crate::evaluate`]) and publishes the
//! directory as a whole. [`ablation`] trains several stage-2 variants from one stage 1.

pub mod ablation;
mod classic;
mod footprint;
mod gaussian;
mod naf;
mod run_dir;
mod setup;

pub use footprint::footprint;
pub use run_dir::{Manifest, RunDir};
pub use setup::{Checkpointing, Outcome, RunOptions};

use crate::{MethodConfig, Result};
use prism_domain::scene::Scene;

/// Reconstruct `scene` with `config` into `dir` and publish it.
pub fn run(
    config: &MethodConfig,
    scene: &Scene,
    mut dir: RunDir,
    options: &RunOptions,
) -> Result<Outcome> {
    options.check(config)?;
    dir.write_text(RunDir::CONFIG, &config.resolved_yaml()?)?;
    let metrics = match config {
        MethodConfig::Classic(c) => classic::run(c, scene, &mut dir, options)?,
        MethodConfig::Gaussian(c) => gaussian::run(c, scene, &mut dir, options)?,
        MethodConfig::Naf(c) => naf::run(c, scene, &mut dir, options)?,
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

#[cfg(test)]
mod gaussian_tests;
#[cfg(test)]
mod resume_tests;
#[cfg(test)]
pub(crate) mod tests;
