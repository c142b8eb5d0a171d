//! A Gaussian method's run: its checkpoints set up, then `r2gs` ([`crate::methods::r2gs`]:
//! every channel on its own) or `4dsg-stage1` / `4dsg` ([`crate::methods::fourdsg`]: stage 1's
//! shared geometry, the spectral stage, held-out channels predicted), then what every Gaussian
//! run ends with ([`crate::gaussians::finish`]).

use crate::Result;
use crate::evaluate::Metrics;
use crate::gaussians::finish::{Outputs, Trained, finish};
use crate::gaussians::train::{Checkpoints, Journal};
use crate::gaussians::{GaussianConfig, GaussianMethod};
use crate::methods::{fourdsg, r2gs};
use crate::record::RunDir;
use crate::record::fingerprint::Fingerprint;
use crate::record::log::RunLog;
use crate::setup::{RunOptions, Setup};
use prism_domain::scene::Scene;

/// Run a Gaussian method on `scene` into `dir` (see the module docs).
pub(super) fn run(
    config: &GaussianConfig,
    scene: &Scene,
    dir: &mut RunDir,
    options: &RunOptions,
) -> Result<Option<Metrics>> {
    config.validate()?;
    let setup = Setup::new(scene, config.holdout_indices(scene)?, options.observer)?;
    let device = &options.device;
    let checkpoints = checkpoints(config, scene, options)?;
    let (mut journal, observed, predicted, trained) = match config.method {
        GaussianMethod::R2gs => {
            let mut journal =
                Journal::new(RunLog::create(&dir.file(RunDir::LOG))?, options.observer);
            journal.checkpoints = checkpoints;
            let (observed, models) = r2gs::train(config, &setup, dir, device, &mut journal)?;
            (journal, observed, None, Trained::PerChannel(models))
        }
        GaussianMethod::Stage1 | GaussianMethod::FourDsg => {
            let (mut journal, shared) = fourdsg::run::shared_geometry(
                config,
                &setup,
                dir,
                device,
                options.from_geometry,
                options.observer,
                checkpoints,
            )?;
            let (observed, predicted, s) = fourdsg::run::spectral(
                config,
                &setup,
                shared,
                dir,
                device,
                &mut journal,
                options.evaluation,
            )?;
            (journal, observed, predicted, s.trained())
        }
    };
    let out = Outputs {
        observed,
        predicted,
        trained,
    };
    finish(config, &setup, dir, &mut journal, out, options.evaluation)
}

/// The run's checkpoints, when `options` ask for them: saved with the run's fingerprint (the
/// scene, the settings, and whether stage 1 came from a stage-1 checkpoint), and read back
/// when resuming.
fn checkpoints<'a>(
    config: &GaussianConfig,
    scene: &Scene,
    options: &RunOptions<'a>,
) -> Result<Option<Checkpoints<'a>>> {
    let Some(c) = &options.checkpoint else {
        return Ok(None);
    };
    let from_geometry = serde_json::Value::Bool(options.from_geometry.is_some());
    let fingerprint = Fingerprint::new(config, scene, &[], &[("from_geometry", from_geometry)])?;
    let checkpoints = Checkpoints::new(c.file(config.checkpoint_every, fingerprint));
    if c.resume {
        checkpoints.resume_from_file().map(Some)
    } else {
        Ok(Some(checkpoints))
    }
}
