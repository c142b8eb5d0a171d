//! What a saved training state depends on, to refuse continuing it with another scene or other
//! settings: the stage-1 checkpoint ([`crate::methods::fourdsg::stage1::checkpoint`]) and the resume file
//! ([`super::resume`]).

use crate::{Error, Result};
use prism_domain::scene::Scene;
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// The scene's data and the settings a saved state was trained with.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Fingerprint {
    pub scene: String,
    /// FNV-1a (64 bit, hex) of the scene's geometry, projections, availability and structural
    /// projections.
    pub scene_digest: String,
    /// The config without the keys the state does not depend on (stage-1 checkpoints written
    /// before resume files existed call it `stage1`).
    #[serde(alias = "stage1")]
    pub settings: Value,
    /// The defaults of the config type the settings come from (not saved): what a setting absent
    /// from an older file stands for.
    #[serde(skip)]
    defaults: Value,
    /// The settings left out (not saved): also left out of a saved state's settings when the
    /// two are compared, so a state written before a key was ignored still serves.
    #[serde(skip)]
    ignored: Vec<String>,
}

/// Two fingerprints are equal when their scene and settings are.
impl PartialEq for Fingerprint {
    fn eq(&self, o: &Self) -> bool {
        (&self.scene, &self.scene_digest, &self.settings)
            == (&o.scene, &o.scene_digest, &o.settings)
    }
}

/// Settings no saved state depends on: where it runs and how often it is saved.
const NEVER: [&str; 2] = ["device", "checkpoint_every"];

/// Settings added with a default that differs from what a file written before them was trained
/// with: their absence from a saved state stands for this value, not for today's default.
const BEFORE: [(&str, &str); 1] = [("views_per_step", "one")];

impl Fingerprint {
    /// The fingerprint of `config` on `scene`, leaving out the keys `ignore` (dotted for a key
    /// inside a section, `loss.tv_guide`) and [`NEVER`]; `extra` entries are added to the
    /// settings (options outside the config).
    pub fn new<C: Serialize + Default>(
        config: &C,
        scene: &Scene,
        ignore: &[&str],
        extra: &[(&str, Value)],
    ) -> Result<Self> {
        let mut settings = serde_json::to_value(config)
            .map_err(|e| Error::invalid("config", format!("not serialisable: {e}")))?;
        let ignored: Vec<String> = ignore.iter().chain(&NEVER).map(|k| k.to_string()).collect();
        for key in &ignored {
            remove_key(&mut settings, key);
        }
        if let Value::Object(map) = &mut settings {
            for (key, v) in extra {
                map.insert(key.to_string(), v.clone());
            }
        }
        let mut defaults = serde_json::to_value(C::default())
            .map_err(|e| Error::invalid("config", format!("not serialisable: {e}")))?;
        if let Value::Object(map) = &mut defaults {
            for (key, v) in BEFORE {
                if map.contains_key(key) {
                    map.insert(key.to_string(), Value::from(v));
                }
            }
        }
        Ok(Fingerprint {
            scene: scene.name.clone(),
            scene_digest: scene_digest(scene),
            settings,
            defaults,
            ignored,
        })
    }

    /// Why a state saved with fingerprint `self` cannot serve a run with `wanted`, if it
    /// cannot. A setting added after the state was written is absent from it; the state was
    /// trained with that setting's default (of `wanted`'s config type).
    pub fn mismatch(&self, wanted: &Fingerprint) -> Option<String> {
        if self.scene != wanted.scene || self.scene_digest != wanted.scene_digest {
            return Some(format!(
                "it was trained on scene `{}` (digest {}), this run's scene is `{}` (digest {})",
                self.scene, self.scene_digest, wanted.scene, wanted.scene_digest
            ));
        }
        let mut saved = self.settings.clone();
        for key in &wanted.ignored {
            remove_key(&mut saved, key);
        }
        let (Value::Object(a), Value::Object(b)) = (&saved, &wanted.settings) else {
            return (saved != wanted.settings).then(|| "the settings differ".into());
        };
        let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
        keys.sort();
        keys.dedup();
        let stored = |k: &String| a.get(k).or_else(|| wanted.defaults.get(k));
        let differ: Vec<String> = keys
            .into_iter()
            .filter(|k| stored(k) != b.get(*k))
            .map(|k| {
                let show = |v: Option<&Value>| v.map_or("(absent)".into(), Value::to_string);
                format!(
                    "`{k}` (saved {}, this run {})",
                    show(stored(k)),
                    show(b.get(k))
                )
            })
            .collect();
        (!differ.is_empty()).then(|| format!("the settings differ: {}", differ.join("; ")))
    }
}

/// Remove the dotted `key` (`loss.tv_guide`) from the sections of `settings`, if present.
fn remove_key(settings: &mut Value, key: &str) {
    let (parent, last) = match key.rsplit_once('.') {
        Some((p, l)) => (Some(p), l),
        None => (None, key),
    };
    let mut node = settings;
    for seg in parent.into_iter().flat_map(|p| p.split('.')) {
        match node.get_mut(seg) {
            Some(n) => node = n,
            None => return,
        }
    }
    if let Value::Object(map) = node {
        map.remove(last);
    }
}

/// FNV-1a over the bytes a training result depends on.
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
