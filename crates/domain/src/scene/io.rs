//! The scene directory format (`docs/scene-format.md`): `scene.yaml` plus `.npy` arrays.
//!
//! Saving is all-or-nothing ([`crate::staged`]): everything is written into a directory beside
//! the target, which is then renamed into place; an existing scene's own files (`scene.yaml` and
//! its arrays) are replaced, anything else in its directory is kept. Loading validates
//! everything, and every error names the file and the field.

use super::npy::{npy_error, read_npy, read_npy_f32};
use super::{Channel, Provenance, Scene, Split, check_metadata};
use crate::geometry::Geometry;
use crate::staged::Staged;
use crate::{Error, Result};
use ndarray::{ArrayD, Dimension};
use ndarray_npy::{ReadNpyError, WriteNpyExt};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::ffi::OsString;
use std::fs;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Name of the metadata file inside a scene directory.
pub const SCENE_FILE: &str = "scene.yaml";
/// The format version this code reads and writes.
pub const FORMAT_VERSION: u32 = 1;

const PROJECTIONS: &str = "projections";
const AVAILABILITY: &str = "availability";
const REFERENCES: &str = "references";
const STRUCTURAL: &str = "structural";
const FRACTIONS: &str = "fractions";

/// The units block: fixed values, written so that a reader never has to guess.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Units {
    length: String,
    angle: String,
    projections: String,
    attenuation: String,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            length: "mm".into(),
            angle: "rad".into(),
            projections: "line_integral".into(),
            attenuation: "mm^-1".into(),
        }
    }
}

impl Units {
    fn check(&self) -> Result<()> {
        let want = Units::default();
        for (field, got, expected) in [
            ("units.length", &self.length, &want.length),
            ("units.angle", &self.angle, &want.angle),
            ("units.projections", &self.projections, &want.projections),
            ("units.attenuation", &self.attenuation, &want.attenuation),
        ] {
            if got != expected {
                return Err(Error::invalid(
                    field,
                    format!("`{got}` is not supported; Prism scenes use `{expected}`"),
                ));
            }
        }
        Ok(())
    }
}

/// One `.npy` file of the scene: its name inside the directory, dtype and shape.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArrayEntry {
    file: String,
    dtype: String,
    shape: Vec<usize>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Arrays {
    projections: ArrayEntry,
    availability: ArrayEntry,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    references: Option<ArrayEntry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    structural: Option<ArrayEntry>,
    /// `[material][z][y][x]` volume fractions of a simulated object (names in `materials`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fractions: Option<ArrayEntry>,
}

/// `scene.yaml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    format_version: u32,
    name: String,
    #[serde(default)]
    units: Units,
    geometry: Geometry,
    channels: Vec<Channel>,
    split: Split,
    #[serde(default)]
    provenance: Provenance,
    /// The materials of `arrays.fractions`, in its order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    materials: Vec<crate::physics::Material>,
    arrays: Arrays,
}

fn entry(name: &str, dtype: &str, shape: &[usize]) -> ArrayEntry {
    ArrayEntry {
        file: format!("{name}.npy"),
        dtype: dtype.into(),
        shape: shape.to_vec(),
    }
}

impl Scene {
    /// Write the scene into directory `dir` (created, or replaced if it holds a scene) without
    /// ever leaving a half-written scene: see the module documentation. The scene is validated
    /// first. An existing `dir` that is neither empty nor a scene is refused.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        self.save_with(dir.as_ref(), |_| Ok(()))
    }

    /// [`save`](Self::save) with a checkpoint called at each stage (`"written"` once the new
    /// scene is complete in its temporary directory, `"swapped"` once the old scene has been
    /// moved aside): tests inject failures there.
    pub(super) fn save_with(
        &self,
        dir: &Path,
        checkpoint: impl Fn(&str) -> Result<()>,
    ) -> Result<()> {
        self.validate()?;
        if dir.exists() && !is_replaceable(dir)? {
            return Err(Error::invalid(
                "dir",
                format!(
                    "`{}` exists and is not a Prism scene (no {SCENE_FILE}); refusing to replace it",
                    dir.display()
                ),
            ));
        }
        let staged = Staged::create(dir)?;
        self.write_files(staged.path())?;
        checkpoint("written")?;
        staged.publish_with(owned_files, |at| match at {
            "swapped" => checkpoint("swapped"),
            _ => Ok(()),
        })
    }

    fn write_files(&self, dir: &Path) -> Result<()> {
        let proj_shape = self.projections.shape().to_vec();
        let mut arrays = Arrays {
            projections: entry(PROJECTIONS, "f32", &proj_shape),
            availability: entry(AVAILABILITY, "bool", self.availability.shape()),
            references: None,
            structural: None,
            fractions: None,
        };
        write_npy(&dir.join(&arrays.projections.file), &self.projections)?;
        write_npy(&dir.join(&arrays.availability.file), &self.availability)?;
        if let Some(r) = &self.references {
            let e = entry(REFERENCES, "f32", r.shape());
            write_npy(&dir.join(&e.file), r)?;
            arrays.references = Some(e);
        }
        if let Some(s) = &self.structural {
            let e = entry(STRUCTURAL, "f32", s.shape());
            write_npy(&dir.join(&e.file), s)?;
            arrays.structural = Some(e);
        }
        if let Some(m) = &self.materials {
            let e = entry(FRACTIONS, "f32", m.fractions.shape());
            write_npy(&dir.join(&e.file), &m.fractions)?;
            arrays.fractions = Some(e);
        }
        let file = SceneFile {
            format_version: FORMAT_VERSION,
            name: self.name.clone(),
            units: Units::default(),
            geometry: self.geometry.clone(),
            channels: self.channels.clone(),
            split: self.split.clone(),
            provenance: self.provenance.clone(),
            materials: self
                .materials
                .as_ref()
                .map(|m| m.materials.clone())
                .unwrap_or_default(),
            arrays,
        };
        let path = dir.join(SCENE_FILE);
        let text = serde_yaml_ng::to_string(&file)
            .map_err(|e| Error::invalid(SCENE_FILE, e.to_string()))?;
        let write = || -> std::io::Result<()> {
            let mut f = fs::File::create(&path)?;
            std::io::Write::write_all(&mut f, text.as_bytes())?;
            f.sync_all()
        };
        write().map_err(|e| Error::io(&path, e))?;
        crate::staged::sync_dir(dir);
        Ok(())
    }

    /// Read and validate the scene in directory `dir`. Errors name the file and the field.
    pub fn load(dir: impl AsRef<Path>) -> Result<Scene> {
        let dir = dir.as_ref();
        let yaml = dir.join(SCENE_FILE);
        let text = fs::read_to_string(&yaml).map_err(|e| Error::io(&yaml, e))?;
        let file: SceneFile =
            serde_yaml_ng::from_str(&text).map_err(|e| crate::yaml::error(&yaml, &e))?;
        let in_yaml = |e: Error| e.in_file(&yaml);
        if file.format_version != FORMAT_VERSION {
            return Err(Error::field(
                &yaml,
                "format_version",
                format!(
                    "version {} is not supported (this build reads version {FORMAT_VERSION})",
                    file.format_version
                ),
            ));
        }
        file.units.check().map_err(in_yaml)?;
        let g = &file.geometry;
        let (c, v) = (file.channels.len(), g.views());
        let (rows, cols) = (g.detector.rows, g.detector.cols);
        let [nz, ny, nx] = g.volume.shape_zyx();
        let a = &file.arrays;
        // The view count (angles vs arrays) before the split, whose indices depend on it.
        g.validate()
            .map_err(|e| e.under("geometry").in_file(&yaml))?;
        check_declared(
            &yaml,
            PROJECTIONS,
            &a.projections,
            &["f32"],
            &[c, v, rows, cols],
        )?;
        check_metadata(g, &file.channels, &file.split).map_err(in_yaml)?;

        let projections = read_f32(dir, &yaml, PROJECTIONS, &a.projections, &[c, v, rows, cols])?;
        let availability = read_availability(dir, &yaml, &a.availability, &[v, c])?;
        let references = match &a.references {
            Some(e) => Some(read_f32(dir, &yaml, REFERENCES, e, &[c, nz, ny, nx])?),
            None => None,
        };
        let structural = match &a.structural {
            Some(e) => Some(read_f32(dir, &yaml, STRUCTURAL, e, &[v, rows, cols])?),
            None => None,
        };
        let m = file.materials.len();
        let materials = match &a.fractions {
            Some(e) => Some(super::MaterialMaps {
                materials: file.materials.clone(),
                fractions: into_dim(read_f32(dir, &yaml, FRACTIONS, e, &[m, nz, ny, nx])?)?,
            }),
            None if m > 0 => {
                return Err(Error::field(
                    &yaml,
                    "materials",
                    "listed without `arrays.fractions`",
                ));
            }
            None => None,
        };
        let scene = Scene {
            name: file.name,
            geometry: file.geometry,
            channels: file.channels,
            projections: into_dim(projections)?,
            availability: into_dim(availability)?,
            references: references.map(into_dim).transpose()?,
            split: file.split,
            provenance: file.provenance,
            structural: structural.map(into_dim).transpose()?,
            materials,
        };
        let at = |entry: &ArrayEntry| dir.join(&entry.file);
        scene
            .check_projections()
            .map_err(|e| e.in_file(at(&a.projections)))?;
        scene
            .check_availability()
            .map_err(|e| e.in_file(at(&a.availability)))?;
        if let Some(e) = &a.references {
            scene.check_references().map_err(|err| err.in_file(at(e)))?;
        }
        if let Some(e) = &a.structural {
            scene.check_structural().map_err(|err| err.in_file(at(e)))?;
        }
        if let Some(e) = &a.fractions {
            scene.check_materials().map_err(|err| err.in_file(at(e)))?;
        }
        Ok(scene)
    }
}

/// True when `dir` may be replaced by a save: an empty directory or a Prism scene.
fn is_replaceable(dir: &Path) -> Result<bool> {
    if !dir.is_dir() {
        return Ok(false);
    }
    if dir.join(SCENE_FILE).is_file() {
        return Ok(true);
    }
    let mut entries = fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    Ok(entries.next().is_none())
}

/// Write an array and flush it to disk (so that the rename that publishes it is durable).
fn write_npy<A: WriteNpyExt + ?Sized>(path: &Path, array: &A) -> Result<()> {
    let f = fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut w = BufWriter::new(f);
    array
        .write_npy(&mut w)
        .map_err(|e| Error::field(path, "data", format!("writing the array failed: {e}")))?;
    let f = w
        .into_inner()
        .map_err(|e| Error::io(path, e.into_error()))?;
    f.sync_all().map_err(|e| Error::io(path, e))
}

/// The entries a saved scene owns: `scene.yaml` and the arrays it lists (the standard array
/// names when its `scene.yaml` cannot be read).
fn owned_files(dir: &Path) -> Result<BTreeSet<OsString>> {
    let mut owned: BTreeSet<OsString> = [SCENE_FILE.into()].into();
    let listed = fs::read_to_string(dir.join(SCENE_FILE))
        .ok()
        .and_then(|t| serde_yaml_ng::from_str::<SceneFile>(&t).ok());
    match listed {
        Some(f) => {
            let a = f.arrays;
            for e in [
                Some(a.projections),
                Some(a.availability),
                a.references,
                a.structural,
                a.fractions,
            ]
            .into_iter()
            .flatten()
            {
                owned.insert(e.file.into());
            }
        }
        None => {
            for n in [PROJECTIONS, AVAILABILITY, REFERENCES, STRUCTURAL, FRACTIONS] {
                owned.insert(format!("{n}.npy").into());
            }
        }
    }
    Ok(owned)
}

/// A `.npy` file named by `entry` inside `dir`, checked to be a bare file name.
fn array_path(dir: &Path, yaml: &Path, key: &str, entry: &ArrayEntry) -> Result<PathBuf> {
    let name = Path::new(&entry.file);
    let bare = name.components().count() == 1
        && matches!(
            name.components().next(),
            Some(std::path::Component::Normal(_))
        );
    if !bare {
        return Err(Error::field(
            yaml,
            format!("arrays.{key}.file"),
            format!(
                "`{}` must be a file name inside the scene directory",
                entry.file
            ),
        ));
    }
    let path = dir.join(name);
    if !path.is_file() {
        return Err(Error::field(
            &path,
            format!("arrays.{key}.file"),
            "the array file is missing",
        ));
    }
    Ok(path)
}

/// Check a declared shape (in `scene.yaml`) or a file's shape against the one the metadata
/// implies. For the projections, a differing view count is reported against
/// `geometry.angles_rad`.
fn check_array_shape(
    key: &str,
    found: &[usize],
    expected: &[usize],
    file: &Path,
    field: &str,
    yaml: &Path,
) -> Result<()> {
    if found == expected {
        return Ok(());
    }
    let view_axis = match key {
        PROJECTIONS => Some(1),
        AVAILABILITY | STRUCTURAL => Some(0),
        _ => None,
    };
    if let Some(k) = view_axis
        && found.len() == expected.len()
        && (0..found.len()).all(|i| i == k || found[i] == expected[i])
    {
        let holder = if file == yaml {
            format!("{field} in {}", yaml.display())
        } else {
            file.display().to_string()
        };
        return Err(Error::field(
            yaml,
            "geometry.angles_rad",
            format!(
                "lists {} angles but {holder} has {} views",
                expected[k], found[k]
            ),
        ));
    }
    Err(Error::field(
        file,
        field,
        format!("wrong shape: expected {expected:?}, found {found:?}"),
    ))
}

fn read_f32(
    dir: &Path,
    yaml: &Path,
    key: &str,
    entry: &ArrayEntry,
    expected: &[usize],
) -> Result<ArrayD<f32>> {
    check_declared(yaml, key, entry, &["f32"], expected)?;
    let path = array_path(dir, yaml, key, entry)?;
    let a = read_npy_f32(&path, key)?;
    check_array_shape(key, a.shape(), expected, &path, key, yaml)?;
    Ok(a)
}

/// Availability: bool (`|b1`) or u8 (`|u1`, 0 or 1).
fn read_availability(
    dir: &Path,
    yaml: &Path,
    entry: &ArrayEntry,
    expected: &[usize],
) -> Result<ArrayD<bool>> {
    let key = AVAILABILITY;
    check_declared(yaml, key, entry, &["bool", "u8"], expected)?;
    let path = array_path(dir, yaml, key, entry)?;
    let want = "bool ('|b1') or u8 ('|u1')";
    let a = match read_npy::<bool>(&path) {
        Ok(a) => a,
        Err(ReadNpyError::WrongDescriptor(_)) => {
            let u = read_npy::<u8>(&path).map_err(|e| npy_error(&path, key, want, e))?;
            if let Some((i, x)) = u.indexed_iter().find(|(_, x)| **x > 1) {
                let idx: String = i.slice().iter().map(|k| format!("[{k}]")).collect();
                return Err(Error::field(
                    &path,
                    format!("{key}{idx}"),
                    format!("u8 availability must be 0 or 1 (found {x})"),
                ));
            }
            u.mapv(|x| x == 1)
        }
        Err(e) => return Err(npy_error(&path, key, want, e)),
    };
    check_array_shape(key, a.shape(), expected, &path, key, yaml)?;
    Ok(a)
}

/// The dtype and shape `scene.yaml` declares for an array must be the expected ones.
fn check_declared(
    yaml: &Path,
    key: &str,
    entry: &ArrayEntry,
    dtypes: &[&str],
    expected: &[usize],
) -> Result<()> {
    if !dtypes.contains(&entry.dtype.as_str()) {
        return Err(Error::field(
            yaml,
            format!("arrays.{key}.dtype"),
            format!(
                "`{}` is not allowed here (expected {dtypes:?})",
                entry.dtype
            ),
        ));
    }
    check_array_shape(
        key,
        &entry.shape,
        expected,
        yaml,
        &format!("arrays.{key}.shape"),
        yaml,
    )
}

/// Convert a shape-checked dynamic array to its static dimension.
fn into_dim<T, D: Dimension>(a: ArrayD<T>) -> Result<ndarray::Array<T, D>> {
    let ndim = a.ndim();
    a.into_dimensionality::<D>().map_err(|_| {
        Error::invalid(
            "arrays",
            format!("an array has {ndim} axes where {:?} were expected", D::NDIM),
        )
    })
}
