//! A Gaussian method's run: its checkpoints set up, then `r2gs` ([`crate::methods::r2gs`]:
//! every channel on its own) or `4dsg-stage1` / `4dsg` ([`crate::methods::fourdsg`]: stage 1's
//! shared geometry, the spectral stage, held-out channels predicted), then what every Gaussian
//! run ends with ([`crate::gaussians::finish`]).

use crate::Result;
use crate::evaluate::Metrics;
use crate::gaussians::GeometryConfig;
use crate::gaussians::finish::{Outputs, Trained, finish};
use crate::gaussians::train::{Checkpoints, Journal};
use crate::methods::fourdsg::FourDsgConfig;
use crate::methods::r2gs::R2gsConfig;
use crate::methods::{Method, fourdsg, r2gs};
use crate::record::RunDir;
use crate::record::fingerprint::Fingerprint;
use crate::record::log::RunLog;
use crate::setup::{RunOptions, Setup};
use prism_domain::scene::Scene;

/// A Gaussian method's configuration.
#[derive(Clone, Copy)]
pub(super) enum Gaussian<'a> {
    R2gs(&'a R2gsConfig),
    FourDsg(&'a FourDsgConfig),
}

impl<'a> Gaussian<'a> {
    fn geometry(self) -> &'a GeometryConfig {
        match self {
            Gaussian::R2gs(c) => &c.geometry,
            Gaussian::FourDsg(c) => &c.geometry,
        }
    }

    fn method(self) -> Method {
        match self {
            Gaussian::R2gs(_) => Method::R2gs,
            Gaussian::FourDsg(c) => c.method.into(),
        }
    }
}

/// Run a Gaussian method on `scene` into `dir` (see the module docs).
pub(super) fn run(
    config: Gaussian,
    scene: &Scene,
    dir: &mut RunDir,
    options: &RunOptions,
) -> Result<Option<Metrics>> {
    let held = match config {
        Gaussian::R2gs(c) => {
            c.geometry.validate()?;
            Vec::new()
        }
        Gaussian::FourDsg(c) => {
            c.validate()?;
            c.holdout_indices(scene)?
        }
    };
    let setup = Setup::new(scene, held, options)?;
    let device = &options.device;
    let checkpoints = checkpoints(config, scene, options)?;
    let (mut journal, observed, predicted, trained) = match config {
        Gaussian::R2gs(c) => {
            let mut journal =
                Journal::new(RunLog::create(&dir.file(RunDir::LOG))?, options.observer);
            journal.checkpoints = checkpoints;
            let (observed, models) = r2gs::train(c, &setup, dir, device, &mut journal)?;
            (journal, observed, None, Trained::PerChannel(models))
        }
        Gaussian::FourDsg(c) => {
            let (mut journal, shared) = fourdsg::run::shared_geometry(
                c,
                &setup,
                dir,
                device,
                options.from_geometry,
                options.observer,
                checkpoints,
            )?;
            let (observed, predicted, s) = fourdsg::run::spectral(
                c,
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
    let projection = &config.geometry().projection;
    let method = config.method().name();
    finish(
        method,
        projection,
        &setup,
        dir,
        &mut journal,
        out,
        options.evaluation,
    )
}

/// The run's checkpoints, when `options` ask for them: saved with the run's fingerprint (the
/// scene, the settings, and whether stage 1 came from a stage-1 checkpoint), and read back
/// when resuming.
fn checkpoints<'a>(
    config: Gaussian,
    scene: &Scene,
    options: &RunOptions<'a>,
) -> Result<Option<Checkpoints<'a>>> {
    let Some(c) = &options.checkpoint else {
        return Ok(None);
    };
    let from_geometry = serde_json::Value::Bool(options.from_geometry.is_some());
    let extra = [("from_geometry", from_geometry)];
    let fingerprint = match config {
        Gaussian::R2gs(c) => Fingerprint::new(c, scene, &[], &extra)?,
        Gaussian::FourDsg(c) => Fingerprint::new(c, scene, &[], &extra)?,
    };
    let every = config.geometry().checkpoint_every;
    let checkpoints = Checkpoints::new(c.file(every, fingerprint));
    if c.resume {
        checkpoints.resume_from_file().map(Some)
    } else {
        Ok(Some(checkpoints))
    }
}
