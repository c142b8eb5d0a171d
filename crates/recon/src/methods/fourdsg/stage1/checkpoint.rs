//! The stage-1 checkpoint of a 4D-SG run: `geometry.safetensors` in the run directory.
//!
//! Written when stage 1 ends (methods `4dsg` and `4dsg-stage1`), it holds everything the spectral
//! stage starts from: the shared Gaussians' raw parameters **with their Adam state** (the
//! spectral stage continues it), the world normalisation, the structural views, the stage-1
//! summary and the run log so far. `prism recon … --from-geometry <run dir | file>` skips stage 1
//! and continues from the checkpoint: the spectral stage starts from exactly what an
//! uninterrupted run's would, so on the same device its losses and volumes are the same (a test
//! checks it on the CPU). Uses: a long run split across job time limits, spectral-stage variants
//! from one stage 1, stage 1 on one device and the spectral stage on another.
//!
//! Format: safetensors with float32 tensors `<group>`, `<group>.m1` and `<group>.m2` (value,
//! Adam first and second moments) for the groups `means [K,3]`, `scales_raw [K,3]`,
//! `rotations [K,4]` and `densities_raw [K,1]` (normalised world, as in [`crate::gaussians::io`]), and
//! string metadata (JSON values): `format` (`prism-geometry/1`), `steps` (Adam steps per group),
//! `world`, `bounds`, `views` (the structural views), `stage` (the stage-1 summary), `log` (the
//! log so far) and `fingerprint` (the scene and the stage-1 settings; resuming with a different
//! scene or different stage-1 settings is refused, naming what differs).

use super::super::config::FourDsgConfig;
use super::SharedGeometry;
use crate::gaussians::World;
use crate::gaussians::host::ScaleBounds;
use crate::gaussians::state::{ModelMeta, ModelState};
use crate::gaussians::train::StageReport;
pub use crate::record::fingerprint::Fingerprint;
use crate::record::log::SavedLog;
use crate::record::tensors::{TensorFile, Tensors, json_meta};
use crate::{Error, Result};
use burn::tensor::Device;
use prism_domain::scene::Scene;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// File name of the checkpoint in a run directory.
pub const GEOMETRY_FILE: &str = "geometry.safetensors";
const FORMAT: &str = "prism-geometry/1";

/// What a stage-1 result depends on: the scene and the config without the settings stage 1
/// does not read (`method`, `stage2`, `density_iterations`, `eval_every`, and the loss's
/// channel settings: stage 1 fits one common density, so `loss.tv_guide` and
/// `loss.tv_channel_weight` do not reach it).
pub fn fingerprint(config: &FourDsgConfig, scene: &Scene) -> Result<Fingerprint> {
    Fingerprint::new(
        config,
        scene,
        &[
            "method",
            "stage2",
            "density_iterations",
            "eval_every",
            "loss.tv_guide",
            "loss.tv_channel_weight",
        ],
        &[],
    )
}

/// Everything stage 1 hands on: the shared geometry, its stage summary and the log so far.
pub struct Checkpoint {
    pub shared: SharedGeometry,
    pub stage: StageReport,
    pub log: SavedLog,
}

/// Write the checkpoint to `path` (see the module docs).
pub fn save(path: &Path, c: &Checkpoint, fingerprint: &Fingerprint) -> Result<()> {
    let state = ModelState::of(&c.shared.model);
    let mut tensors = Tensors::default();
    state.add_to("", &mut tensors);
    let meta = state.meta();
    let meta: HashMap<String, String> = [
        ("format", FORMAT.to_string()),
        ("steps", json_meta(path, "steps", &meta.steps)?),
        ("world", json_meta(path, "world", &c.shared.world)?),
        ("bounds", json_meta(path, "bounds", &meta.bounds)?),
        ("views", json_meta(path, "views", &c.shared.views)?),
        ("stage", json_meta(path, "stage", &c.stage)?),
        ("log", json_meta(path, "log", &c.log)?),
        ("fingerprint", json_meta(path, "fingerprint", fingerprint)?),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    tensors.write(path, meta)
}

/// The checkpoint file a `--from-geometry` argument names: the file, or [`GEOMETRY_FILE`] in a
/// run directory.
pub fn locate(arg: &Path) -> PathBuf {
    if arg.is_dir() {
        arg.join(GEOMETRY_FILE)
    } else {
        arg.to_path_buf()
    }
}

/// Read a checkpoint for a run of `scene` whose stage 1 would have had `wanted`; errors name the
/// file and the field, and say what differs when the checkpoint belongs to another scene or
/// settings. Its structural views must be distinct training views of `scene`.
pub fn load(
    path: &Path,
    wanted: &Fingerprint,
    scene: &Scene,
    device: &Device,
) -> Result<Checkpoint> {
    let f = TensorFile::open(path, FORMAT)?;
    let fingerprint: Fingerprint = f.json("fingerprint")?;
    if let Some(why) = fingerprint.mismatch(wanted) {
        return Err(Error::field(
            path,
            "metadata.fingerprint",
            format!("this stage-1 checkpoint does not belong to this run: {why}"),
        ));
    }
    let steps: Vec<i32> = f.json("steps")?;
    let steps: [i32; 4] = steps.try_into().map_err(|s: Vec<i32>| {
        Error::field(
            path,
            "metadata.steps",
            format!("expected 4 entries, got {}", s.len()),
        )
    })?;
    let world: World = f.json("world")?;
    let bounds: ScaleBounds = f.json("bounds")?;
    let views: Vec<usize> = f.json("views")?;
    check_views(&views, scene).map_err(|why| Error::field(path, "metadata.views", why))?;
    let stage: StageReport = f.json("stage")?;
    let log: SavedLog = f.json("log")?;
    let meta = ModelMeta {
        steps,
        bounds,
        channels: 1,
    };
    let model = ModelState::read(&f, "", &meta)?.to_model(device);
    Ok(Checkpoint {
        shared: SharedGeometry {
            model,
            world,
            views,
        },
        stage,
        log,
    })
}

/// Why `views` cannot be the structural views of a stage 1 on `scene`, if they cannot.
fn check_views(views: &[usize], scene: &Scene) -> std::result::Result<(), String> {
    if views.is_empty() {
        return Err("no structural view".into());
    }
    prism_domain::indices::distinct_below(views, scene.n_views())
        .map_err(|fault| format!("view {fault}"))?;
    let train = scene.train_views();
    match views.iter().find(|v| !train.contains(v)) {
        Some(v) => Err(format!(
            "view {v} is not one of the scene's {} training views",
            train.len()
        )),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaussians::ProjectionConfig;
    use prism_render::ProjectionMode;

    #[test]
    fn settings_a_checkpoint_predates_count_as_their_defaults() {
        let scene = crate::pipeline::tests::scene();
        let config = FourDsgConfig::default();
        let mut old = fingerprint(&config, &scene).unwrap();
        // A checkpoint written before `projection` existed.
        old.settings.as_object_mut().unwrap().remove("projection");
        assert_eq!(old.mismatch(&fingerprint(&config, &scene).unwrap()), None);
        let mut exact = config.clone();
        exact.geometry.projection = ProjectionConfig {
            mode: ProjectionMode::Exact,
            ..ProjectionConfig::default()
        };
        let why = old.mismatch(&fingerprint(&exact, &scene).unwrap()).unwrap();
        assert!(
            why.contains("`projection`") && why.contains("affine") && why.contains("exact"),
            "{why}"
        );
        // Other settings still count.
        let mut seeded = config;
        seeded.geometry.seed = 7;
        let why = old
            .mismatch(&fingerprint(&seeded, &scene).unwrap())
            .unwrap();
        assert!(
            why.contains("`seed`") && !why.contains("projection"),
            "{why}"
        );
    }

    #[test]
    fn a_checkpoint_from_before_views_per_step_was_trained_one_view_at_a_time() {
        // Its absence stands for `one`, the only behaviour then, not for today's `cover`.
        let scene = crate::pipeline::tests::scene();
        let config = FourDsgConfig::default();
        let mut old = fingerprint(&config, &scene).unwrap();
        old.settings
            .as_object_mut()
            .unwrap()
            .remove("views_per_step");
        let why = old
            .mismatch(&fingerprint(&config, &scene).unwrap())
            .unwrap();
        assert!(
            why.contains("`views_per_step`") && why.contains("one") && why.contains("cover"),
            "{why}"
        );
        let mut one = config;
        one.geometry.views_per_step = crate::gaussians::config::ViewsPerStep::One;
        assert_eq!(old.mismatch(&fingerprint(&one, &scene).unwrap()), None);
    }
}
