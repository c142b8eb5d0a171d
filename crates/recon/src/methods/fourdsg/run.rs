//! A 4D-SG run's two stages in a run directory: stage 1's shared geometry (trained and
//! checkpointed, or continued from a checkpoint) and the spectral stage on it (the model saved,
//! held-out channels predicted and scored).

use super::config::FourDsgConfig;
use super::query::basis::save_basis;
use super::query::{BASIS_FILE, Holdout, predict_holdout};
use super::stage1::checkpoint::{self, Checkpoint};
use super::stage1::{SharedGeometry, train_shared_geometry};
use super::stage2::{Spectral, train_spectral};
use crate::Result;
use crate::device::host_values;
use crate::evaluate::Evaluation;
use crate::gaussians::io::{ModelInfo, save_model, write_ply};
use crate::gaussians::train::{Checkpoints, Journal};
use crate::gaussians::volume::volumes_with;
use crate::record::RunDir;
use crate::record::log::RunLog;
use crate::setup::{Setup, Volumes};
use burn::tensor::Device;
use ndarray::Axis;
use prism_domain::observe::{Level, Observer};
use std::path::Path;

/// Stage 1 in `dir`: trained (its checkpoint saved there), or continued from the checkpoint
/// `from_geometry` (a file, or a run directory holding one) of the same scene and stage-1
/// settings; with the journal the run goes on with (keeping `checkpoints`).
pub(crate) fn shared_geometry<'o>(
    config: &FourDsgConfig,
    setup: &Setup,
    dir: &mut RunDir,
    device: &Device,
    from_geometry: Option<&Path>,
    observer: &'o dyn Observer,
    checkpoints: Option<Checkpoints<'o>>,
) -> Result<(Journal<'o>, SharedGeometry)> {
    let fingerprint = checkpoint::fingerprint(config, &setup.observed)?;
    if let Some(arg) = from_geometry {
        let c = checkpoint::load(
            &checkpoint::locate(arg),
            &fingerprint,
            &setup.observed,
            device,
        )?;
        let mut journal = Journal::new(RunLog::resume(&dir.file(RunDir::LOG), &c.log)?, observer);
        journal.checkpoints = checkpoints;
        journal.stages.push(c.stage);
        return Ok((journal, c.shared));
    }
    let mut journal = Journal::new(RunLog::create(&dir.file(RunDir::LOG))?, observer);
    journal.checkpoints = checkpoints;
    let shared = train_shared_geometry(
        config,
        &setup.observed,
        &setup.scoring,
        device,
        &mut journal,
    )?;
    let c = Checkpoint {
        shared,
        stage: journal.stages.last().cloned().expect("stage 1 just ran"),
        log: journal.log.saved(),
    };
    // Writing the checkpoint is not training time: it is booked with evaluation.
    let path = dir.file(RunDir::GEOMETRY);
    journal
        .log
        .evaluating(|| checkpoint::save(&path, &c, &fingerprint))?;
    Ok((journal, c.shared))
}

/// The spectral stage on the shared geometry; saves the model and returns the observed
/// channels' volumes and, for held-out channels, the predicted ones.
pub(crate) fn spectral(
    config: &FourDsgConfig,
    setup: &Setup,
    shared: SharedGeometry,
    dir: &mut RunDir,
    device: &Device,
    journal: &mut Journal,
    eval: &Evaluation,
) -> Result<(Volumes, Option<Volumes>, Spectral)> {
    let scene = &*setup.observed;
    let m = scene.n_channels();
    let s = train_spectral(config, scene, &setup.scoring, shared, device, journal)?;
    let info = ModelInfo {
        basis: s.basis.is_some(),
        ..ModelInfo::new(
            setup.full,
            scene,
            &(0..m).collect::<Vec<_>>(),
            config.geometry.projection,
        )
    };
    let raw_host = host_values(&s.raw);
    save_model(
        &dir.file(RunDir::MODEL),
        &s.model,
        Some(raw_host.clone()),
        &s.world,
        &info,
    )?;
    write_ply(
        &dir.file("gaussians.ply"),
        &s.model,
        Some(raw_host),
        &s.world,
        &info.channels,
    )?;
    if let Some(head) = &s.basis {
        save_basis(&dir.file(BASIS_FILE), head, &s.model)?;
    }
    let v = volumes_with(&s.model, s.raw.clone(), &scene.geometry.volume, &s.world)?;
    let observed = (0..m)
        .map(|c| v.index_axis(Axis(0), c).to_owned())
        .collect();
    if setup.held.is_empty() {
        return Ok((observed, None, s));
    }
    let hold = Holdout {
        model: &s.model,
        raw: &s.raw,
        world: &s.world,
        info: &info,
        basis: s.basis.as_ref(),
    };
    let (predicted, scores) = predict_holdout(&hold, setup.full, &setup.held, eval)?;
    dir.write_json(RunDir::HOLDOUT, &scores)?;
    for s in &scores {
        let db = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.2} dB"));
        journal.observer.note(
            Level::Info,
            &format!(
                "held out {:>10}  volume PSNR {}  projection PSNR {} ({} views)",
                s.label,
                db(s.volume.as_ref().map(|v| v.psnr)),
                db(s.proj_psnr),
                s.views
            ),
        );
    }
    Ok((observed, Some(predicted), s))
}
