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
//! `rotations [K,4]` and `densities_raw [K,1]` (normalised world, as in [`crate::gaussian::io`]), and
//! string metadata (JSON values): `format` (`prism-geometry/1`), `steps` (Adam steps per group),
//! `world`, `bounds`, `views` (the structural views), `stage` (the stage-1 summary), `log` (the
//! log so far) and `fingerprint` (the scene and the stage-1 settings; resuming with a different
//! scene or different stage-1 settings is refused, naming what differs).

use super::SharedGeometry;
use crate::gaussian::adam::AdamParam;
use crate::gaussian::host::ScaleBounds;
use crate::gaussian::io::TensorFile;
use crate::gaussian::{GaussianConfig, GaussianMethod, GaussianModel, World, host_values, upload};
use crate::train::StageReport;
use crate::train::log::SavedLog;
use crate::{Error, Result};
use burn::tensor::Device;
use prism_domain::scene::Scene;
use safetensors::{Dtype, tensor::TensorView};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// File name of the checkpoint in a run directory.
pub const GEOMETRY_FILE: &str = "geometry.safetensors";
const FORMAT: &str = "prism-geometry/1";
/// Tensor names and widths of the parameter groups, in [`GaussianModel`] order.
const GROUPS: [(&str, usize); 4] = [
    ("means", 3),
    ("scales_raw", 3),
    ("rotations", 4),
    ("densities_raw", 1),
];

/// What a stage-1 result depends on: the scene's data and the stage-1 settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fingerprint {
    pub scene: String,
    /// FNV-1a (64 bit, hex) of the training scene's geometry, projections, availability and
    /// structural projections.
    pub scene_digest: String,
    /// The config without the settings stage 1 does not read (`method`, `stage2`,
    /// `density_iterations`, `device`, `eval_every`).
    pub stage1: Value,
}

impl Fingerprint {
    pub fn new(config: &GaussianConfig, scene: &Scene) -> Result<Self> {
        let mut stage1 = serde_json::to_value(config)
            .map_err(|e| Error::invalid("config", format!("not serialisable: {e}")))?;
        if let Value::Object(map) = &mut stage1 {
            for key in [
                "method",
                "stage2",
                "density_iterations",
                "device",
                "eval_every",
            ] {
                map.remove(key);
            }
        }
        Ok(Fingerprint {
            scene: scene.name.clone(),
            scene_digest: scene_digest(scene),
            stage1,
        })
    }

    /// Why a checkpoint with fingerprint `self` cannot serve a run with `wanted`, if it cannot.
    fn mismatch(&self, wanted: &Fingerprint) -> Option<String> {
        if self.scene != wanted.scene || self.scene_digest != wanted.scene_digest {
            return Some(format!(
                "it was trained on scene `{}` (digest {}), this run's scene is `{}` (digest {})",
                self.scene, self.scene_digest, wanted.scene, wanted.scene_digest
            ));
        }
        let (Value::Object(a), Value::Object(b)) = (&self.stage1, &wanted.stage1) else {
            return (self.stage1 != wanted.stage1).then(|| "stage-1 settings differ".into());
        };
        let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
        keys.sort();
        keys.dedup();
        // A setting added after the checkpoint was written is absent from it; the checkpoint was
        // trained with that setting's default.
        let defaults = serde_json::to_value(GaussianConfig::new(GaussianMethod::FourDsg))
            .expect("the default config serialises");
        let stored = |k: &String| a.get(k).or_else(|| defaults.get(k));
        let differ: Vec<String> = keys
            .into_iter()
            .filter(|k| stored(k) != b.get(*k))
            .map(|k| {
                let show = |v: Option<&Value>| v.map_or("(absent)".into(), Value::to_string);
                format!(
                    "`{k}` (checkpoint {}, config {})",
                    show(stored(k)),
                    show(b.get(k))
                )
            })
            .collect();
        (!differ.is_empty()).then(|| format!("stage-1 settings differ: {}", differ.join("; ")))
    }
}

/// FNV-1a over the bytes a stage-1 result depends on.
fn scene_digest(scene: &Scene) -> String {
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ b as u64).wrapping_mul(PRIME);
        }
    };
    eat(serde_json::to_string(&scene.geometry)
        .expect("geometry serialises")
        .as_bytes());
    for v in scene.projections.iter() {
        eat(&v.to_le_bytes());
    }
    for &a in scene.availability.iter() {
        eat(&[a as u8]);
    }
    if let Some(s) = &scene.structural {
        for v in s.iter() {
            eat(&v.to_le_bytes());
        }
    }
    format!("{h:016x}")
}

/// Everything stage 1 hands on: the shared geometry, its stage summary and the log so far.
pub struct Checkpoint {
    pub shared: SharedGeometry,
    pub stage: StageReport,
    pub log: SavedLog,
}

fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn json<T: Serialize>(path: &Path, key: &str, v: &T) -> Result<String> {
    serde_json::to_string(v)
        .map_err(|e| Error::field(path, format!("metadata.{key}"), e.to_string()))
}

/// Write the checkpoint to `path` (see the module docs).
pub fn save(path: &Path, c: &Checkpoint, fingerprint: &Fingerprint) -> Result<()> {
    let model = &c.shared.model;
    let params = [
        &model.means,
        &model.scales,
        &model.rotations,
        &model.densities,
    ];
    let k = model.len();
    let mut data: Vec<(String, Vec<u8>, Vec<usize>)> = Vec::new();
    let mut steps = Vec::new();
    for ((name, width), p) in GROUPS.iter().zip(params) {
        let (m1, m2, s) = p.state();
        for (suffix, t) in [("", &p.value), (".m1", m1), (".m2", m2)] {
            data.push((
                format!("{name}{suffix}"),
                bytes(&host_values(t)),
                vec![k, *width],
            ));
        }
        steps.push(s);
    }
    let views: Vec<(&str, TensorView)> = data
        .iter()
        .map(|(n, b, s)| {
            TensorView::new(Dtype::F32, s.clone(), b)
                .map(|v| (n.as_str(), v))
                .map_err(|e| Error::field(path, n.clone(), e.to_string()))
        })
        .collect::<Result<_>>()?;
    let meta: HashMap<String, String> = [
        ("format", FORMAT.to_string()),
        ("steps", json(path, "steps", &steps)?),
        ("world", json(path, "world", &c.shared.world)?),
        ("bounds", json(path, "bounds", &model.bounds)?),
        ("views", json(path, "views", &c.shared.views)?),
        ("stage", json(path, "stage", &c.stage)?),
        ("log", json(path, "log", &c.log)?),
        ("fingerprint", json(path, "fingerprint", fingerprint)?),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    crate::gaussian::io::write_safetensors(path, views, meta)
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

/// Read a checkpoint for a run whose stage 1 would have had `wanted`; errors name the file and
/// the field, and say what differs when the checkpoint belongs to another scene or settings.
pub fn load(path: &Path, wanted: &Fingerprint, device: &Device) -> Result<Checkpoint> {
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
    if steps.len() != GROUPS.len() {
        return Err(Error::field(
            path,
            "metadata.steps",
            format!("expected {} entries, got {}", GROUPS.len(), steps.len()),
        ));
    }
    let world: World = f.json("world")?;
    let bounds: ScaleBounds = f.json("bounds")?;
    bounds.validate().map_err(|e| e.in_file(path))?;
    let views: Vec<usize> = f.json("views")?;
    let stage: StageReport = f.json("stage")?;
    let log: SavedLog = f.json("log")?;

    // Every tensor has the same K rows, and only finite entries.
    let k = f.rows("means", 3)?.len() / 3;
    if k == 0 {
        return Err(Error::field(path, "means", "no Gaussians"));
    }
    let tensor = |name: &str, width: usize| -> Result<Vec<f32>> {
        let v = f.rows(name, width)?;
        if v.len() != k * width {
            return Err(Error::field(
                path,
                name,
                format!("expected {k} rows like `means`, got {}", v.len() / width),
            ));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(Error::field(path, name, format!("entry {i} is not finite")));
        }
        Ok(v)
    };
    let mut params = Vec::new();
    for ((name, width), s) in GROUPS.iter().zip(&steps) {
        let part = |suffix: &str| -> Result<_> {
            Ok(upload(
                tensor(&format!("{name}{suffix}"), *width)?,
                *width,
                device,
            ))
        };
        params.push(AdamParam::with_state(
            part("")?,
            part(".m1")?,
            part(".m2")?,
            *s,
        ));
    }
    let [means, scales, rotations, densities] =
        <[AdamParam; 4]>::try_from(params).unwrap_or_else(|_| unreachable!("four groups"));
    Ok(Checkpoint {
        shared: SharedGeometry {
            model: GaussianModel {
                means,
                scales,
                rotations,
                densities,
                bounds,
            },
            world,
            views,
        },
        stage,
        log,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaussian::ProjectionConfig;
    use prism_render::ProjectionMode;

    #[test]
    fn settings_a_checkpoint_predates_count_as_their_defaults() {
        let scene = crate::pipeline::tests::scene();
        let config = GaussianConfig::new(GaussianMethod::FourDsg);
        let mut old = Fingerprint::new(&config, &scene).unwrap();
        // A checkpoint written before `projection` existed.
        old.stage1.as_object_mut().unwrap().remove("projection");
        assert_eq!(
            old.mismatch(&Fingerprint::new(&config, &scene).unwrap()),
            None
        );
        let mut exact = config.clone();
        exact.projection = ProjectionConfig {
            mode: ProjectionMode::Exact,
            ..ProjectionConfig::default()
        };
        let why = old
            .mismatch(&Fingerprint::new(&exact, &scene).unwrap())
            .unwrap();
        assert!(
            why.contains("`projection`") && why.contains("affine") && why.contains("exact"),
            "{why}"
        );
        // Other settings still count.
        let mut seeded = config;
        seeded.seed = 7;
        let why = old
            .mismatch(&Fingerprint::new(&seeded, &scene).unwrap())
            .unwrap();
        assert!(
            why.contains("`seed`") && !why.contains("projection"),
            "{why}"
        );
    }
}
