//! Import of R²-Gaussian / NAF case folders (`meta_data.json`, `proj_train/*.npy`,
//! `proj_test/*.npy`, `vol_gt.npy`) as a one-channel scene, in the file's own length unit.
//!
//! * geometry: the `scanner` block through [`R2Scanner`]; view angles (radians) from the
//!   `proj_train` then `proj_test` lists, so the training views come first;
//! * projections: one f32 `[rows][cols]` line-integral image per view, same orientation as Prism;
//! * `vol_gt.npy` (f32 `[x][y][z]`) becomes the reference volume, transposed to `[z][y][x]`;
//! * the channel is labelled `r2` with a [`SpectralCoordinate::Unspecified`] coordinate: the case
//!   records no spectrum.
//!
//! R²-Gaussian's normalised world (scale 2 / max(sVoxel)) is the trainer's business, not the
//! loader's.

use super::npy::read_npy_f32;
use super::{Channel, Provenance, Scene, SpectralCoordinate, Split, check_finite};
use crate::geometry::R2Scanner;
use crate::{Error, Result};
use ndarray::{Array2, Array3, Array4, Axis};
use serde::Deserialize;
use serde::de::DeserializeOwned;
use std::path::{Component, Path, PathBuf};

/// Name of the metadata file of an R²-Gaussian case.
pub const R2_META_FILE: &str = "meta_data.json";

#[derive(Debug, Deserialize)]
struct R2View {
    file_path: String,
    angle: f64,
}

/// Deserialise `meta[key]` (or `default` when absent); errors name the key and the file.
fn take<T: DeserializeOwned>(
    meta: &serde_json::Value,
    key: &str,
    file: &Path,
    default: Option<T>,
) -> Result<T> {
    match meta.get(key) {
        Some(v) => T::deserialize(v).map_err(|e| Error::field(file, key, e.to_string())),
        None => default.ok_or_else(|| Error::field(file, key, "missing field")),
    }
}

/// A path named in `meta_data.json`, which must stay inside the case folder.
fn inside(dir: &Path, rel: &str, file: &Path, field: &str) -> Result<PathBuf> {
    let p = Path::new(rel);
    let ok = p.components().next().is_some()
        && p.components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    if !ok {
        return Err(Error::field(
            file,
            field,
            format!("`{rel}` must be a relative path inside the case folder"),
        ));
    }
    let path = dir.join(p);
    if !path.is_file() {
        return Err(Error::field(&path, field, "the file is missing"));
    }
    Ok(path)
}

impl Scene {
    /// Load a scene directory (`scene.yaml`), or an R²-Gaussian case folder (`meta_data.json`,
    /// no `scene.yaml`) as [`Scene::load_r2`] does.
    pub fn open(dir: impl AsRef<Path>) -> Result<Scene> {
        let dir = dir.as_ref();
        if dir.join("meta_data.json").is_file() && !dir.join("scene.yaml").exists() {
            Scene::load_r2(dir)
        } else {
            Scene::load(dir)
        }
    }

    /// Load an R²-Gaussian case folder as a one-channel scene (see the module documentation).
    /// Errors name the file and the field (`scanner.DSO`, `proj_test[2].file_path`, `vol`…).
    pub fn load_r2(dir: impl AsRef<Path>) -> Result<Scene> {
        let dir = dir.as_ref();
        let meta_path = dir.join(R2_META_FILE);
        let text = std::fs::read_to_string(&meta_path).map_err(|e| Error::io(&meta_path, e))?;
        let meta: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| Error::field(&meta_path, ".", format!("invalid JSON: {e}")))?;
        let scanner: R2Scanner = take(&meta, "scanner", &meta_path, None)?;
        let train: Vec<R2View> = take(&meta, "proj_train", &meta_path, None)?;
        let test: Vec<R2View> = take(&meta, "proj_test", &meta_path, Some(Vec::new()))?;
        if train.is_empty() {
            return Err(Error::field(&meta_path, "proj_train", "lists no views"));
        }
        let views: Vec<(String, &R2View)> = train
            .iter()
            .enumerate()
            .map(|(i, v)| (format!("proj_train[{i}]"), v))
            .chain(
                test.iter()
                    .enumerate()
                    .map(|(i, v)| (format!("proj_test[{i}]"), v)),
            )
            .collect();
        for (field, v) in &views {
            if !v.angle.is_finite() {
                return Err(Error::field(
                    &meta_path,
                    format!("{field}.angle"),
                    format!("must be finite (got {})", v.angle),
                ));
            }
        }
        let angles = views.iter().map(|(_, v)| v.angle).collect();
        let geometry = scanner
            .to_geometry(angles)
            .map_err(|e| e.in_file(&meta_path))?;
        let (rows, cols) = (geometry.detector.rows, geometry.detector.cols);

        // Each image is checked against `scanner.nDetector` before it is used, and the first
        // before the stack is allocated: the stack's size then rests on a file that holds it,
        // not on the metadata alone.
        let image = |(field, v): &(String, &R2View)| -> Result<ndarray::Array2<f32>> {
            let path = inside(dir, &v.file_path, &meta_path, &format!("{field}.file_path"))?;
            let img = read_npy_f32(&path, field)?;
            if img.shape() != [rows, cols] {
                return Err(Error::field(
                    &path,
                    field.as_str(),
                    format!(
                        "wrong shape: expected [{rows}, {cols}] (scanner.nDetector), found {:?}",
                        img.shape()
                    ),
                ));
            }
            check_finite(field, img.view(), |_| "projection".into())
                .map_err(|e| e.in_file(&path))?;
            img.into_dimensionality::<ndarray::Ix2>()
                .map_err(|e| Error::field(&path, field.as_str(), e.to_string()))
        };
        let first = image(&views[0])?;
        let mut projections = Array4::<f32>::zeros((1, views.len(), rows, cols));
        projections
            .slice_mut(ndarray::s![0, 0, .., ..])
            .assign(&first);
        for (k, view) in views.iter().enumerate().skip(1) {
            projections
                .slice_mut(ndarray::s![0, k, .., ..])
                .assign(&image(view)?);
        }

        let vol_name: Option<String> = take(&meta, "vol", &meta_path, Some(None))?;
        let vol_path = match vol_name {
            Some(name) => Some(inside(dir, &name, &meta_path, "vol")?),
            None => Some(dir.join("vol_gt.npy")).filter(|p| p.is_file()),
        };
        let references = match vol_path {
            None => None,
            Some(path) => {
                let v = read_npy_f32(&path, "vol")?;
                let g = &geometry.volume;
                if v.shape() != [g.nx, g.ny, g.nz] {
                    return Err(Error::field(
                        &path,
                        "vol",
                        format!(
                            "wrong shape: expected [{}, {}, {}] ([x][y][z], scanner.nVoxel), \
                             found {:?}",
                            g.nx,
                            g.ny,
                            g.nz,
                            v.shape()
                        ),
                    ));
                }
                check_finite("vol", v.view(), |_| "[x][y][z] order".into())
                    .map_err(|e| e.in_file(&path))?;
                let zyx: Array3<f32> = v
                    .into_dimensionality::<ndarray::Ix3>()
                    .map_err(|e| Error::field(&path, "vol", e.to_string()))?
                    .permuted_axes([2, 1, 0])
                    .as_standard_layout()
                    .into_owned();
                Some(zyx.insert_axis(Axis(0)))
            }
        };

        let n_train = train.len();
        let name = dir
            .canonicalize()
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| "r2".into());
        let scene = Scene {
            name,
            channels: vec![Channel::new("r2", SpectralCoordinate::Unspecified)],
            availability: Array2::from_elem((views.len(), 1), true),
            projections,
            references,
            split: Split {
                train: (0..n_train).collect(),
                test: (n_train..views.len()).collect(),
            },
            provenance: Provenance {
                generator: format!("R²-Gaussian case folder ({R2_META_FILE})"),
                source_data: vec![dir.display().to_string()],
                ..Provenance::default()
            },
            structural: None,
            materials: None,
            geometry,
        };
        scene.validate().map_err(|e| e.in_file(&meta_path))?;
        Ok(scene)
    }
}
