//! Saving and loading trained Gaussians.
//!
//! * **safetensors** (`.safetensors`, readable from Python with `safetensors.numpy.load_file`):
//!   float32 tensors `means [K,3]`, `scales_raw [K,3]`, `rotations [K,4]` (w, x, y, z),
//!   `densities_raw [K,M]` in the normalised world, plus string metadata `format`
//!   (`prism-gaussians/1`), `world_scale` (normalised units per mm), `density_scale` (mm⁻¹ per
//!   normalised density unit), `scale_min`, `scale_max` (normalised units) and `info` (JSON
//!   [`ModelInfo`]: channel labels, τ and physical coordinates of the density columns, the scan
//!   geometry, the projection settings it was trained with). Physical values: centre_mm = means / world_scale,
//!   σ_mm = (min + (max − min)·sigmoid(scales_raw)) / world_scale,
//!   μ (mm⁻¹) = softplus(densities_raw) · density_scale.
//! * **PLY** (binary little-endian, for point-cloud viewers): per vertex `x y z` (mm),
//!   `scale_0..2` (σ in mm), `rot_0..3` (unit quaternion w, x, y, z) and one `density_<c>`
//!   property per channel (mm⁻¹).

use super::config::ProjectionConfig;
use super::host::{HostGaussians, ScaleBounds, softplus};
use super::model::GaussianModel;
use super::world::World;
use crate::record::tensors::{TensorFile, Tensors, bytes};
use crate::{Error, Result};
use burn::tensor::Device;
use prism_domain::geometry::Geometry;
use prism_domain::scene::Scene;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fs;
use std::io::{BufWriter, Write};
use std::path::Path;

const FORMAT: &str = "prism-gaussians/1";

/// What the density columns mean and where the model lives (stored as JSON metadata `info`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    /// One label per density column.
    pub channels: Vec<String>,
    /// τ ∈ [0, 1] of each column (increasing for spectral models).
    pub tau: Vec<f64>,
    /// Physical coordinate of each column (keV, kVp, λ, …) and its unit.
    pub coordinates: Vec<f64>,
    pub unit: String,
    /// Coordinate values mapped to τ = 0 and τ = 1 (the scene's channel range).
    pub coordinate_range: [f64; 2],
    /// The scan geometry (millimetres), for voxelizing and rendering queries.
    pub geometry: Geometry,
    /// How the model was trained to project; queries render the same way (absent in files
    /// written before the setting existed, which were all trained with the default).
    #[serde(default)]
    pub projection: ProjectionConfig,
    /// Every channel is monoenergetic (its coordinate is its photon energy), so a coordinate is
    /// an energy (false in files written before the field existed).
    #[serde(default)]
    pub monoenergetic: bool,
    /// The run carries a basis head: its materials are in `basis.safetensors` beside the model,
    /// which monoenergetic queries need (false in files written before the field existed).
    #[serde(default)]
    pub basis: bool,
}

impl ModelInfo {
    /// The info of a model whose density columns are the `channels` of `observed` (a subset of
    /// `full`'s channels, τ as in `full`), trained with `projection`.
    pub fn new(
        full: &Scene,
        observed: &Scene,
        channels: &[usize],
        projection: ProjectionConfig,
    ) -> Self {
        let coords: Vec<f64> = full.channels.iter().map(|c| c.coordinate.value()).collect();
        let lo = coords.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = coords.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let ch = |c: usize| &observed.channels[c];
        ModelInfo {
            channels: channels.iter().map(|&c| ch(c).label.clone()).collect(),
            tau: channels.iter().map(|&c| ch(c).tau).collect(),
            coordinates: channels.iter().map(|&c| ch(c).coordinate.value()).collect(),
            unit: ch(channels[0]).coordinate.unit().to_string(),
            coordinate_range: [lo, hi],
            geometry: observed.geometry.clone(),
            projection,
            monoenergetic: full.channels.iter().all(|c| {
                matches!(
                    c.coordinate,
                    prism_domain::scene::SpectralCoordinate::Energy { .. }
                )
            }),
            basis: false,
        }
    }

    /// τ of a physical coordinate value.
    pub fn tau_of(&self, value: f64) -> f64 {
        let [lo, hi] = self.coordinate_range;
        if hi > lo {
            (value - lo) / (hi - lo)
        } else {
            0.0
        }
    }
}

/// Write `model` as safetensors (see the module docs).
pub fn save_model(
    path: &Path,
    model: &GaussianModel,
    raw: Option<Vec<f32>>,
    world: &World,
    info: &ModelInfo,
) -> Result<()> {
    let mut h = model.to_host();
    if let Some(r) = raw {
        h.channels = info.channels.len();
        h.densities = r;
    }
    h.validate().map_err(|e| e.in_file(path))?;
    let k = h.len();
    let mut tensors = Tensors::default();
    tensors.f32("means", &h.means, [k, 3]);
    tensors.f32("scales_raw", &h.scales, [k, 3]);
    tensors.f32("rotations", &h.rotations, [k, 4]);
    tensors.f32("densities_raw", &h.densities, [k, h.channels]);
    let meta: HashMap<String, String> = [
        ("format", FORMAT.to_string()),
        ("world_scale", world.scale.to_string()),
        ("density_scale", world.density_scale.to_string()),
        ("scale_min", model.bounds.min.to_string()),
        ("scale_max", model.bounds.max.to_string()),
        (
            "info",
            serde_json::to_string(info).expect("model info serialises"),
        ),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    tensors.write(path, meta)
}

/// A model read back from [`save_model`]'s file.
pub struct LoadedModel {
    pub model: GaussianModel,
    pub world: World,
    pub info: ModelInfo,
}

/// Read a safetensors model; errors name the file and the tensor or metadata key.
pub fn load_model(path: &Path, device: &Device) -> Result<LoadedModel> {
    let f = TensorFile::open(path, FORMAT)?;
    let num = |k: &str| -> Result<f64> { f.json(k) };
    let info: ModelInfo = f.json("info")?;
    info.geometry
        .validate()
        .map_err(|e| e.in_file(path).under("metadata.info.geometry"))?;
    let tensor = |name: &str, cols: usize| f.rows(name, cols);
    let m = info.channels.len();
    let host = HostGaussians {
        channels: m,
        means: tensor("means", 3)?,
        scales: tensor("scales_raw", 3)?,
        rotations: tensor("rotations", 4)?,
        densities: tensor("densities_raw", m)?,
    };
    host.validate().map_err(|e| e.in_file(path))?;
    let bounds = ScaleBounds {
        min: num("scale_min")?,
        max: num("scale_max")?,
    };
    bounds.validate().map_err(|e| e.in_file(path))?;
    let world = World {
        scale: num("world_scale")?,
        density_scale: num("density_scale")?,
    };
    world
        .validate()
        .map_err(|e| e.in_file(path).under("metadata"))?;
    Ok(LoadedModel {
        model: GaussianModel::new(&host, bounds, device),
        world,
        info,
    })
}

/// Write `model` as a binary PLY point cloud in physical units (see the module docs).
pub fn write_ply(
    path: &Path,
    model: &GaussianModel,
    raw: Option<Vec<f32>>,
    world: &World,
    labels: &[String],
) -> Result<()> {
    let mut h = model.to_host();
    if let Some(r) = raw {
        h.channels = labels.len();
        h.densities = r;
    }
    let k = h.len();
    let m = h.channels;
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment Prism Gaussians: positions and scales in mm, densities in 1/mm\nelement vertex {k}\n"
    );
    for p in [
        "x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
    ] {
        header += &format!("property float {p}\n");
    }
    for c in 0..m {
        let label = labels.get(c).map(String::as_str).unwrap_or("");
        let safe: String = label
            .chars()
            .map(|ch| if ch.is_ascii_alphanumeric() { ch } else { '_' })
            .collect();
        header += &format!("property float density_{c}_{safe}\n");
    }
    header += "end_header\n";
    let io = |e| Error::io(path, e);
    let file = fs::File::create(path).map_err(io)?;
    let mut w = BufWriter::new(file);
    w.write_all(header.as_bytes()).map_err(io)?;
    let inv = 1.0 / world.scale;
    for i in 0..k {
        let q = &h.rotations[4 * i..4 * i + 4];
        let qn = q.iter().map(|v| v * v).sum::<f32>().sqrt();
        let q: Vec<f32> = if qn > 0.0 {
            q.iter().map(|v| v / qn).collect()
        } else {
            vec![1.0, 0.0, 0.0, 0.0]
        };
        let mut row: Vec<f32> = Vec::with_capacity(10 + m);
        row.extend(
            h.means[3 * i..3 * i + 3]
                .iter()
                .map(|&v| (v as f64 * inv) as f32),
        );
        row.extend(
            h.scales[3 * i..3 * i + 3]
                .iter()
                .map(|&r| (model.bounds.activate(r as f64) * inv) as f32),
        );
        row.extend(q);
        row.extend(
            h.densities[m * i..m * i + m]
                .iter()
                .map(|&r| (softplus(r as f64) * world.density_scale) as f32),
        );
        w.write_all(&bytes(&row)).map_err(io)?;
    }
    w.flush().map_err(io)
}
