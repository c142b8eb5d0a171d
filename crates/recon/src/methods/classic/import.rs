//! A measured scan into a scene (`prism import`, and the imported scenes of `prism experiment`):
//! the images read and converted ([`prism_domain::import::assemble`]), each channel's
//! rotation axis estimated when asked (`axis:`), each channel's
//! reference reconstructed by a classic method from every view it was measured at, then the
//! training and test views kept.

use super::{ClassicConfig, ClassicMethod, reconstruct_channel};
use crate::algorithms::axis::estimate_axis;
use crate::{Error, Result};
use prism_domain::import::config::ImageSource;
use prism_domain::import::{
    AxisMethod, ImportConfig, ReferenceKind, assemble, read_reference_volume,
};
use prism_domain::observe::{Level, Observer};
use prism_domain::scene::Scene;
use std::path::Path;

/// A channel's reference: reconstructed by a classic method from every view the channel was
/// measured at (`FDK`, or a recon config's path), or a volume read from a file
/// (`reference_volume`, a reconstruction made elsewhere).
#[derive(Clone, Debug)]
pub enum Reference {
    /// The method, and where it came from (`FDK`, or its config's path).
    Recon(ClassicConfig, String),
    Volume(ImageSource),
}

impl Reference {
    /// Where it comes from, for progress and errors: the method or the volume's file.
    pub fn describe(&self) -> String {
        match self {
            Reference::Recon(_, from) => from.clone(),
            Reference::Volume(source) => source.path.display().to_string(),
        }
    }
}

/// Each channel's reference (`select.reference`, or the channel's own `reference` or
/// `reference_volume`), or `None` when the scene gets no references. Config paths are relative to
/// `base`.
pub fn reference_configs(config: &ImportConfig, base: &Path) -> Result<Option<Vec<Reference>>> {
    let read = |path: &Path| -> Result<Reference> {
        let file = base.join(path);
        let text = std::fs::read_to_string(&file).map_err(|e| prism_domain::Error::io(&file, e))?;
        let c = ClassicConfig::from_yaml(&text, &file)?;
        Ok(Reference::Recon(c, path.display().to_string()))
    };
    if let Some(c) = config
        .channels
        .iter()
        .position(|c| c.reference.is_some() && c.reference_volume.is_some())
    {
        return Err(Error::invalid(
            format!("channels[{c}].reference_volume"),
            "give `reference` (a recon config) or `reference_volume` (a volume file), not both",
        ));
    }
    let shared = match &config.select.reference {
        ReferenceKind::None => None,
        ReferenceKind::Fdk => Some(Reference::Recon(
            ClassicConfig::new(ClassicMethod::Fdk),
            "FDK".to_string(),
        )),
        ReferenceKind::Recon(path) => Some(read(path)?),
    };
    let Some(shared) = shared else {
        if let Some((c, field)) = config.channels.iter().enumerate().find_map(|(c, ch)| {
            (ch.reference.is_some().then_some("reference"))
                .or(ch.reference_volume.is_some().then_some("reference_volume"))
                .map(|f| (c, f))
        }) {
            return Err(Error::invalid(
                format!("channels[{c}].{field}"),
                "given, but select.reference is `none`: a scene has references for every \
                 channel or for none",
            ));
        }
        return Ok(None);
    };
    config
        .channels
        .iter()
        .map(|c| match (&c.reference, &c.reference_volume) {
            (Some(path), _) => read(path),
            (None, Some(v)) => Ok(Reference::Volume(v.clone())),
            (None, None) => Ok(shared.clone()),
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

/// The scene of `config` (paths relative to `base`; `text` is its provenance): every channel
/// read, referenced by `references` (one per channel, [`reference_configs`]; `None`: no
/// references) and cut to the selected views. Phases, warnings and each reference's iterations
/// go to `observer`.
pub fn import_scene(
    config: &ImportConfig,
    base: &Path,
    text: &str,
    references: Option<&[Reference]>,
    observer: &dyn Observer,
) -> Result<Scene> {
    let full = import_full(config, base, text, references, observer)?;
    select_views(config, &full)
}

/// `full` (an [`import_full`] scene) cut to the views `config` selects.
pub fn select_views(config: &ImportConfig, full: &Scene) -> Result<Scene> {
    let (train, test) = config.pick_views(full.n_views())?;
    Ok(full.with_views(&train, &test)?)
}

/// The whole scan of `config` with its references, every view a training view: what
/// [`import_scene`] selects from (scenes of one scan at several view counts share it).
pub fn import_full(
    config: &ImportConfig,
    base: &Path,
    text: &str,
    references: Option<&[Reference]>,
    observer: &dyn Observer,
) -> Result<Scene> {
    observer.phase("reading and converting the images", 0);
    let full = assemble(config, base, text)?;
    // Per channel, what the conversion changed: pixels raised to `min_counts` (a warning: the
    // counts were starved), negative line integrals clipped, bad pixels repaired.
    let min_counts = format!(
        "pixels had dark-corrected counts below min_counts = {} and were raised to it",
        config.min_counts
    );
    let tallies = [
        (&full.raised, Level::Warning, min_counts.as_str()),
        (
            &full.clipped,
            Level::Info,
            "negative line integrals set to zero (clip_negative)",
        ),
        (
            &full.bad_pixels,
            Level::Info,
            "bad detector pixels repaired in every image",
        ),
    ];
    for (counts, level, what) in tallies {
        for (ch, n) in full.scene.channels.iter().zip(counts) {
            if *n > 0 {
                observer.note(level, &format!("channel `{}`: {n} {what}", ch.label));
            }
        }
    }
    let mut scene = full.scene;
    if config.axis.method != AxisMethod::Given {
        let estimate = estimate_axis(&scene, &config.axis, observer)?;
        observer.note(
            Level::Info,
            &format!("rotation axis: {}", estimate.describe()),
        );
        scene.geometry.detector.offset_u = estimate.offset_u;
        scene.provenance.axis = Some(estimate);
    }
    let n = scene.n_views();
    if let Some(references) = references {
        let mut volumes = Vec::with_capacity(references.len());
        for (c, reference) in references.iter().enumerate() {
            let label = &scene.channels[c].label;
            let from = reference.describe();
            let v = match reference {
                Reference::Volume(source) => {
                    observer.phase(&format!("reference of `{label}`: read from {from}"), 0);
                    let field = format!("channels[{c}].reference_volume");
                    let shape = scene.geometry.volume.shape_zyx();
                    read_reference_volume(source, &field, base, shape)?
                }
                Reference::Recon(method, _) => {
                    let views: Vec<usize> =
                        (0..n).filter(|&v| scene.availability[[v, c]]).collect();
                    observer.phase(
                        &format!("reference of `{label}`: {from}, {} views", views.len()),
                        method.resolved_iterations() as u64,
                    );
                    reconstruct_channel(
                        method,
                        &scene.geometry,
                        scene.channel_projections(c),
                        &views,
                        &mut |i| observer.progress(i as u64, label),
                    )
                    .map_err(|e| e.under(&format!("reference of channel `{label}` ({from})")))?
                }
            };
            volumes.push(v);
        }
        scene = scene.with_references(volumes)?;
    }
    Ok(scene)
}
