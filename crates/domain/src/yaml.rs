//! Reading YAML files (configs, `scene.yaml`) with errors that name the file and the field.

use crate::{Error, Result};
use serde::de::DeserializeOwned;
use std::path::Path;

/// Read and parse a YAML file.
pub fn read<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    serde_yaml_ng::from_str(&text).map_err(|e| error(path, &e))
}

/// A YAML error as a field error of `file`. serde_yaml_ng prefixes messages with the path of the
/// offending value (`channels[1].coordinate: unknown variant …`); that path becomes the field.
pub fn error(file: &Path, e: &serde_yaml_ng::Error) -> Error {
    let msg = e.to_string();
    let is_path = |p: &str| {
        !p.is_empty()
            && p.chars()
                .all(|ch| ch.is_ascii_alphanumeric() || "_.[]".contains(ch))
    };
    match msg.split_once(": ") {
        Some((path, rest)) if is_path(path) => Error::field(file, path, rest),
        _ => Error::field(file, ".", msg),
    }
}
