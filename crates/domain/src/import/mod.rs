//! Measured projections → a scene: `prism import <import.yaml> -o <scene_dir>`.
//!
//! Each channel (an acquisition: a kVp setting, an energy window) gives its raw counts `I` with
//! flat (open beam) `F` and dark `D` fields, or its line integrals directly. Counts become line
//! integrals `p = −ln((I − D) / (F − D))`, with `I − D` raised to `min_counts` where it is
//! smaller (zero and negative counts: a large finite `p`, and a count of how many) and an error
//! where `F − D ≤ 0` (no beam to normalise by). Rows stored bottom-up (TIGRE) are flipped to
//! Prism's top-down order. Channels may have been measured at a subset of the scan's views
//! (`views`); the scene marks the others unavailable.
//!
//! [`assemble`] builds the full scan (every view); [`Scene::with_views`] keeps the selected
//! training and test views. The full-view FDK reference needs a reconstruction method, so the
//! `prism import` command computes it between the two (`prism_recon`).

pub mod axis;
pub mod bad_pixels;
pub mod config;
mod convert;
#[cfg(test)]
mod curved_tests;
#[cfg(test)]
mod detector_tests;
pub mod fan;
pub mod hdf5;
pub mod images;
pub mod rings;
#[cfg(test)]
mod tests;

pub use crate::scene::{AxisEstimate, AxisMethod};
pub use axis::AxisConfig;
pub use config::{ImportConfig, ReferenceKind};
pub use convert::{clip_negative, line_integrals, transmission};

use crate::geometry::Geometry;
use crate::indices::IndexFault;
use crate::memory::{self, Footprint};
use crate::scene::{Channel, Provenance, Scene, Split, check_finite, check_shape, normalise_tau};
use crate::{Error, Result};
use images::read_stack;
use ndarray::{Array2, Array3, Array4, Axis, s};
use std::path::Path;

/// The whole scan as line integrals, before view selection.
#[derive(Clone, Debug)]
pub struct FullScan {
    /// Every view of the scan for training (`split.train` = all), no references.
    pub scene: Scene,
    /// Per channel: pixels whose dark-corrected counts were raised to `min_counts`.
    pub raised: Vec<usize>,
    /// Per channel: bad detector pixels repaired (`bad_pixels`; 0 for line integrals).
    pub bad_pixels: Vec<usize>,
    /// Per channel: negative line integrals set to zero (`clip_negative`; 0 without it).
    pub clipped: Vec<usize>,
}

/// Read and convert every channel of `config` (paths relative to `base`); `config_text` is kept
/// as the scene's provenance.
pub fn assemble(config: &ImportConfig, base: &Path, config_text: &str) -> Result<FullScan> {
    let (geometry, bottom_up) = config.scan_geometry(base)?;
    let n_views = geometry.views();
    // The images' columns as measured; a curved detector's become the scene's flat line.
    let rebinning = config.rebinning()?;
    let rows = geometry.detector.rows;
    let cols = rebinning
        .as_ref()
        .map_or(geometry.detector.cols, |r| r.curved_cols);
    if config.channels.is_empty() {
        return Err(Error::invalid(
            "channels",
            "an import needs at least one channel",
        ));
    }
    if let Some(r) = &config.rings {
        r.validate(cols)?;
    }
    if let Some(b) = &config.bad_pixels {
        b.validate()?;
    }
    if !(config.min_counts.is_finite() && config.min_counts > 0.0) {
        return Err(Error::invalid(
            "min_counts",
            format!("must be finite and > 0, got {}", config.min_counts),
        ));
    }
    let shared_flat = config
        .flat
        .as_ref()
        .map(|f| mean_image(f, base, "flat", [rows, cols]))
        .transpose()?;
    let shared_dark = config
        .dark
        .as_ref()
        .map(|f| mean_image(f, base, "dark", [rows, cols]))
        .transpose()?;
    let m = config.channels.len();
    let scene_cols = geometry.detector.cols;
    let mut projections = Array4::<f32>::zeros((m, n_views, rows, scene_cols));
    let mut availability = Array2::from_elem((n_views, m), false);
    let mut raised = Vec::with_capacity(m);
    let mut bad_counts = Vec::with_capacity(m);
    let mut clipped = Vec::with_capacity(m);
    let mut channels = Vec::with_capacity(m);
    for (c, src) in config.channels.iter().enumerate() {
        let field = |f: &str| format!("channels[{c}].{f}");
        let views: Vec<usize> = match &src.views {
            Some(v) => v.clone(),
            None => (0..n_views).collect(),
        };
        if let Err(fault) = crate::indices::distinct_below(&views, n_views) {
            let (i, why) = match fault {
                IndexFault::Beyond { at, index, .. } => (
                    at,
                    format!("view {index} is beyond the scan's {n_views} views"),
                ),
                IndexFault::Repeated { at, index } => (
                    at,
                    format!("view {index} is listed twice (each image must be one view)"),
                ),
            };
            return Err(Error::invalid(format!("channels[{c}].views[{i}]"), why));
        }
        let (stack, from) = match (&src.counts, &src.line_integrals) {
            (Some(s), None) => (read_stack(s, base, Some([rows, cols]))?, s),
            (None, Some(s)) => (read_stack(s, base, Some([rows, cols]))?, s),
            _ => {
                return Err(Error::invalid(
                    field("counts"),
                    "give `counts` (with flat and dark fields) or `line_integrals`, one of them",
                ));
            }
        };
        let path = base.join(&from.path);
        let want = [views.len(), rows, cols];
        if stack.shape() != want {
            return Err(Error::field(
                &path,
                "shape",
                format!(
                    "{:?} found; the geometry and the channel's views give [views, rows, cols] = {want:?}",
                    stack.shape()
                ),
            ));
        }
        let mut p = if src.counts.is_some() {
            let flat = match &src.flat {
                Some(f) => Some(mean_image(f, base, &field("flat"), [rows, cols])?),
                None => shared_flat.clone(),
            };
            let dark = match &src.dark {
                Some(f) => Some(mean_image(f, base, &field("dark"), [rows, cols])?),
                None => shared_dark.clone(),
            };
            let Some(flat) = flat else {
                return Err(Error::invalid(
                    field("flat"),
                    "counts need a flat field (the channel's `flat` or the config's)",
                ));
            };
            let dark = dark.unwrap_or_else(|| Array2::zeros((rows, cols)));
            for (what, img) in [("flat", &flat), ("dark", &dark)] {
                if img.shape() != [rows, cols] {
                    return Err(Error::invalid(
                        field(what),
                        format!("{:?} found, the detector is [{rows}, {cols}]", img.shape()),
                    ));
                }
            }
            let at = |e: Error| e.under(&format!("channels[{c}]"));
            let bad = match &config.bad_pixels {
                Some(b) => Some(b.find((&flat - &dark).view()).map_err(at)?),
                None => None,
            };
            bad_counts.push(bad.as_ref().map_or(0, |b| b.iter().filter(|&&x| x).count()));
            let (p, n) = match (&config.rings, &bad) {
                (None, None) => line_integrals(stack, flat.view(), dark.view(), config.min_counts)
                    .map_err(at)?,
                // Bad pixels and stripes are detector faults: repaired in the transmission,
                // before the log.
                (rings, bad) => {
                    let (mut t, n) = transmission(
                        stack,
                        flat.view(),
                        dark.view(),
                        config.min_counts,
                        bad.as_ref(),
                    )
                    .map_err(at)?;
                    if let (Some(b), Some(mask)) = (&config.bad_pixels, bad) {
                        b.repair(&mut t, mask);
                    }
                    if let Some(r) = rings {
                        r.apply(&mut t)?;
                    }
                    t.mapv_inplace(|x| -x.ln());
                    (t, n)
                }
            };
            raised.push(n);
            p
        } else {
            raised.push(0);
            bad_counts.push(0);
            let mut p = stack;
            if let Some(r) = &config.rings {
                r.apply(&mut p)?;
            }
            p
        };
        clipped.push(if config.clip_negative {
            clip_negative(&mut p)
        } else {
            0
        });
        if let Some(r) = &rebinning {
            p = r.apply(&p);
        }
        if bottom_up {
            p.invert_axis(Axis(1));
        }
        for (k, &v) in views.iter().enumerate() {
            projections
                .slice_mut(s![c, v, .., ..])
                .assign(&p.index_axis(Axis(0), k));
            availability[[v, c]] = true;
        }
        channels.push(Channel::new(src.label.clone(), src.coordinate.clone()));
    }
    normalise_tau(&mut channels)?;
    let scene = Scene {
        name: config.name.clone(),
        geometry,
        channels,
        projections,
        availability,
        references: None,
        split: Split::all_train(n_views),
        provenance: Provenance {
            generator: format!("prism import {}", env!("CARGO_PKG_VERSION")),
            config: config_text.to_string(),
            overrides: Vec::new(),
            source_data: config.source_data.clone(),
            licence: config.licence.clone(),
            created_by: String::new(),
            axis: None,
        },
        structural: None,
        materials: None,
    };
    scene.validate()?;
    Ok(FullScan {
        scene,
        raised,
        bad_pixels: bad_counts,
        clipped,
    })
}

/// A channel's `reference_volume` (`source`, paths relative to `base`; `field` names it in
/// errors): its images must be `shape` (`[nz, ny, nx]`, the scene's grid) and finite.
pub fn read_reference_volume(
    source: &config::ImageSource,
    field: &str,
    base: &Path,
    shape: [usize; 3],
) -> Result<Array3<f32>> {
    let v = read_stack(source, base, Some([shape[1], shape[2]])).map_err(|e| e.under(field))?;
    check_shape(field, v.shape(), &shape)
        .and_then(|()| {
            check_finite(field, v.view().into_dyn(), |_| {
                "a voxel of the reference, index [z][y][x]".into()
            })
        })
        .map_err(|e| e.in_file(base.join(&source.path)))?;
    Ok(v)
}

/// The estimated peak memory of importing `config` (image paths relative to `base`), from the
/// config alone (an angle file is read; no image is): the full scan's projections, one
/// channel's images as read (at their raw type's size, else assumed ≤ 4 bytes per value) and
/// as f32, with full-view FDK references one channel's filtered projections and volume, the
/// references while stacked, and the scene of the selected views with its copy of them.
pub fn footprint(config: &ImportConfig, base: &Path) -> Result<Footprint> {
    let (g, _) = config.scan_geometry(base)?;
    let (views, rows, cols) = (g.views(), g.detector.rows, g.detector.cols);
    let m = config.channels.len();
    let pixels = memory::elements("geometry.detector", &[views, rows, cols])?;
    let voxels = memory::elements("geometry.volume", &[g.volume.nz, g.volume.ny, g.volume.nx])?;
    let mut f = Footprint::process();
    f.add(
        format!("projections of the full scan ({m} channels × {views} views × {rows}×{cols})"),
        memory::bytes(pixels, 4 * m),
    );
    let per_value = config
        .channels
        .iter()
        .flat_map(|c| [&c.counts, &c.line_integrals])
        .flatten()
        .map(|s| s.raw.as_ref().map_or(4, |r| r.dtype.size()))
        .max()
        .unwrap_or(4);
    f.add(
        "one channel's images as read and as f32",
        memory::bytes(pixels, per_value + 4),
    );
    if config.rings.is_some() {
        f.add(
            "ring suppression: a few detector rows' sinograms, sorted, ordered and filtered",
            memory::bytes(views * cols, rings::SCRATCH_BYTES * rings::batch_rows()),
        );
    }
    let referenced = config.select.reference != ReferenceKind::None
        || config.channels.iter().any(|c| c.reference.is_some());
    if referenced {
        f.add(
            "full-view reference of one channel (its projections twice, volume and iterates)",
            memory::bytes(pixels, 8).saturating_add(memory::bytes(voxels, 32)),
        );
        f.add(
            format!("reference volumes, twice while stacked or copied ({m} × {voxels} voxels)"),
            memory::bytes(voxels, 8 * m),
        );
    }
    let (train, test) = config.pick_views(views)?;
    let kept = train.len() + test.len();
    f.add(
        format!("the scene's {kept} selected views"),
        memory::bytes(kept * rows * cols, 4 * m),
    );
    Ok(f)
}

/// The mean of a stack of `[rows, cols]` images (flat or dark fields).
fn mean_image(
    source: &config::ImageSource,
    base: &Path,
    field: &str,
    image: [usize; 2],
) -> Result<Array2<f32>> {
    let stack = read_stack(source, base, Some(image)).map_err(|e| e.under(field))?;
    stack
        .mean_axis(Axis(0))
        .ok_or_else(|| Error::invalid(field, "holds no image"))
}

/// Angles from a `.npy` (any numeric type), an HDF5 `dataset`, or a text file of one value per
/// line (`#` comments).
fn read_angles(path: &Path, dataset: Option<&str>) -> Result<Vec<f64>> {
    if let Some(name) = dataset {
        return hdf5::read_vector(path, name);
    }
    if hdf5::is_hdf5(path) {
        return Err(Error::invalid(
            "angles.dataset",
            format!(
                "{} is HDF5: name the dataset holding the angles",
                path.display()
            ),
        ));
    }
    if path.extension().is_some_and(|e| e == "npy") {
        let a = crate::scene::npy::read_npy_any(path, "angles")?;
        return Ok(a.iter().map(|&v| v as f64).collect());
    }
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    text.lines()
        .enumerate()
        .map(|(i, l)| (i, l.split('#').next().unwrap_or("").trim()))
        .filter(|(_, l)| !l.is_empty())
        .map(|(i, l)| {
            l.parse::<f64>()
                .map_err(|e| Error::field(path, format!("line {}", i + 1), e.to_string()))
        })
        .collect()
}

impl ImportConfig {
    /// The full scan's angles in radians (an angle file relative to `base`).
    pub fn angles_rad(&self, base: &Path) -> Result<Vec<f64>> {
        self.angles
            .resolve(|p| read_angles(&base.join(p), self.angles.dataset.as_deref()))
    }

    /// The full scan's geometry (files relative to `base`: angles, vectors) and whether stored
    /// rows run bottom-up.
    pub fn scan_geometry(&self, base: &Path) -> Result<(Geometry, bool)> {
        let vectors = match &self.geometry {
            config::GeometrySource::Vectors(v) => Some(
                read_vector_rows(
                    &base.join(&v.file),
                    v.dataset.as_deref(),
                    v.axes.as_deref(),
                    v.row_len(),
                )
                .map_err(|e| e.under("geometry.vectors"))?,
            ),
            _ => None,
        };
        let angles = match (&vectors, self.angles.is_given()) {
            (Some(_), false) => None,
            _ => Some(self.angles_rad(base)?),
        };
        self.geometry(angles, vectors.as_deref())
    }
}

/// The rows of a vector file: a `[views, width]` `.npy` (f64 or f32), a dataset of an HDF5 /
/// MATLAB -v7.3 file ([`hdf5::read_rows`]) or text with one row per line (numbers separated by
/// spaces or commas, `#` comments).
fn read_vector_rows(
    path: &Path,
    dataset: Option<&str>,
    axes: Option<&str>,
    width: usize,
) -> Result<Vec<Vec<f64>>> {
    if hdf5::is_hdf5(path) {
        let name = dataset.ok_or_else(|| {
            Error::field(
                path,
                "dataset",
                "name the dataset of the vectors in this HDF5 file",
            )
        })?;
        return hdf5::read_rows(path, name, axes, width);
    }
    if dataset.is_some() || axes.is_some() {
        return Err(Error::field(
            path,
            "dataset",
            "`dataset` and `axes` apply to HDF5 / MATLAB -v7.3 files; this is not one",
        ));
    }
    if path.extension().is_some_and(|e| e == "npy") {
        let a = match crate::scene::npy::read_array::<f64, ndarray::Ix2>(path, "file") {
            Ok(a) => a,
            Err(_) => crate::scene::npy::read_array::<f32, ndarray::Ix2>(path, "file")
                .map_err(|_| {
                    Error::field(
                        path,
                        "file",
                        format!("expected a [views, {width}] f64 or f32 array"),
                    )
                })?
                .mapv(f64::from),
        };
        if a.ncols() != width {
            return Err(Error::field(
                path,
                "file",
                format!("has {} columns; a row of vectors has {width}", a.ncols()),
            ));
        }
        return Ok(a.rows().into_iter().map(|r| r.to_vec()).collect());
    }
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let row = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| t.parse::<f64>())
            .collect::<std::result::Result<Vec<f64>, _>>()
            .map_err(|e| Error::field(path, format!("line {}", i + 1), e.to_string()))?;
        if row.len() != width {
            return Err(Error::field(
                path,
                format!("line {}", i + 1),
                format!("holds {} numbers; a row of vectors has {width}", row.len()),
            ));
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(Error::field(path, "file", "holds no row of vectors"));
    }
    Ok(rows)
}

impl Scene {
    /// The scene with `volumes` (one `[z][y][x]` volume per channel, mm⁻¹) as its references.
    pub fn with_references(mut self, volumes: Vec<Array3<f32>>) -> Result<Scene> {
        if volumes.len() != self.n_channels() {
            return Err(Error::invalid(
                "references",
                format!(
                    "{} volumes for {} channels",
                    volumes.len(),
                    self.n_channels()
                ),
            ));
        }
        let views: Vec<_> = volumes.iter().map(|v| v.view()).collect();
        let stacked = ndarray::stack(Axis(0), &views)
            .map_err(|e| Error::invalid("references", e.to_string()))?;
        self.references = Some(stacked);
        self.validate()?;
        Ok(self)
    }

    /// The scene restricted to `train` and `test` views (indices of `self`'s views; the kept
    /// views in increasing order, the split pointing into them).
    pub fn with_views(&self, train: &[usize], test: &[usize]) -> Result<Scene> {
        let n = self.n_views();
        if let Some(v) = train.iter().chain(test).find(|&&v| v >= n) {
            return Err(Error::invalid(
                "split",
                format!("view {v} is beyond the scene's {n} views"),
            ));
        }
        let mut keep: Vec<usize> = train.iter().chain(test).copied().collect();
        keep.sort_unstable();
        keep.dedup();
        if keep.len() != train.len() + test.len() {
            return Err(Error::invalid(
                "split",
                "a view is both a training and a test view",
            ));
        }
        let pos = |v: &usize| keep.binary_search(v).unwrap_or(0);
        // Field by field: `..self.clone()` would copy the whole projection stack first.
        let scene = Scene {
            name: self.name.clone(),
            geometry: self.geometry.with_views(&keep),
            channels: self.channels.clone(),
            projections: self.projections.select(Axis(1), &keep),
            availability: self.availability.select(Axis(0), &keep),
            references: self.references.clone(),
            split: Split {
                train: train.iter().map(pos).collect(),
                test: test.iter().map(pos).collect(),
            },
            provenance: self.provenance.clone(),
            structural: self.structural.as_ref().map(|s| s.select(Axis(0), &keep)),
            materials: self.materials.clone(),
        };
        scene.validate()?;
        Ok(scene)
    }
}
