//! Scene configs (`configs/*.yaml`) → spectral scenes.
//!
//! A config names an object (the built-in analytic phantom, a custom list of ellipsoids, or an HU
//! volume), a scan geometry given by physical sizes and counts, the spectral channels, and optional
//! noise. The pipeline:
//!
//! 1. per-material path lengths along every pixel ray — closed-form ellipsoid chords for phantoms
//!    (exact), or Joseph forward projections of the material fractions on a grid twice as fine as
//!    the reconstruction grid for HU volumes (so reconstructions on the scene grid are not an
//!    inverse crime);
//! 2. per channel, the projections from the path lengths and the reference volume from the
//!    fractions on the scene grid ([`ChannelSpec`]);
//! 3. noise on the training views only (test views stay noise-free for evaluation), each
//!    channel with `noise.i0` photons or, for photon-counting bins, its share of them
//!    ([`Acquisition`]);
//! 4. τ from the channels' physical coordinates, availability (every channel at every view, or
//!    interleaved over the training views ([`Acquisition`]), less the pairs the config drops),
//!    provenance.

mod disturb;

pub use disturb::DisturbSpec;

use crate::geometry::{Beam, Detector, Geometry, VolumeGrid};
use crate::memory::{self, Footprint};
use crate::observe::Observer;
use crate::phantom::hu::{HuMapping, hu_material_volumes};
use crate::phantom::{Component, MaterialVolumes, SpectralPhantom};
use crate::physics::{ChannelSpec, NoiseModel, add_noise};
use crate::projector::Joseph;
use crate::scene::{
    Channel, MaterialMaps, Provenance, Scene, SpectralCoordinate, Split, normalise_tau,
};
use crate::yaml::Overrides;
use crate::{Error, Result};
use ndarray::{Array2, Array3, Array4, Axis, s};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

/// A scene config, as in `configs/*.yaml`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulateConfig {
    pub name: String,
    /// Seed for test-view angles and noise.
    #[serde(default)]
    pub seed: u64,
    pub geometry: GeometrySpec,
    #[serde(with = "serde_yaml_ng::with::singleton_map")]
    pub object: ObjectSpec,
    /// Channels, ordered along the spectral axis.
    pub channels: Vec<ChannelSpec>,
    /// A provided full-spectrum (structural) projection, e.g. the widest photon-counting window.
    #[serde(default)]
    pub structural: Option<ChannelSpec>,
    /// Noise on the training views; absent = noise-free.
    #[serde(default)]
    pub noise: Option<NoiseModel>,
    /// How the channels share the training views and the photons.
    #[serde(default)]
    pub acquisition: Acquisition,
    /// (view, channel) pairs that are not acquired (besides those `acquisition` leaves out).
    #[serde(default)]
    pub missing: Vec<[usize; 2]>,
}

/// How a spectral acquisition shares its views and photons among the channels (YAML
/// `acquisition:`; both fields optional).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Acquisition {
    pub views: ViewSharing,
    pub photons: PhotonSharing,
}

/// Which channels are measured at each training view (test views always have every channel).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewSharing {
    /// Every channel at every view (dual-layer, photon-counting, or one scan per channel at the
    /// same angles).
    #[default]
    Shared,
    /// Channel c at the training views v ≡ c (mod C), C the channel count: fast kV switching,
    /// or sequential scans at offset angles. `geometry.views` counts the distinct angles, so
    /// each channel has about `views / C`.
    Interleaved,
}

/// How many photons each channel receives when `noise` is set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PhotonSharing {
    /// `noise.i0` photons per pixel for every channel (one exposure per channel).
    #[default]
    PerChannel,
    /// `noise.i0` is the tube's photons per pixel over its whole spectrum and each channel
    /// receives its share ([`ChannelSpec::photon_share`]): photon-counting bins split one
    /// exposure. Overlapping windows are sampled independently (their counts are correlated
    /// in a real detector).
    Split,
}

/// Scan geometry by physical sizes and counts.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeometrySpec {
    pub beam: Beam,
    pub dso: f64,
    pub dsd: f64,
    pub detector: DetectorSpec,
    pub volume: VolumeSpec,
    /// Training views, evenly spaced over `total_deg` from `start_deg` (endpoint excluded).
    pub views: usize,
    /// Test views at seeded uniform random angles in [0°, 360°), sorted.
    #[serde(default)]
    pub test_views: usize,
    #[serde(default)]
    pub start_deg: f64,
    #[serde(default = "full_turn_deg")]
    pub total_deg: f64,
    /// Seeded per-view deviations from the circular orbit, stored as per-view vectors (the
    /// fields above stay the nominal scan): `{source_mm, detector_mm, spin_deg, tilt_deg}`, σ each.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub disturb: Option<DisturbSpec>,
}

fn full_turn_deg() -> f64 {
    360.0
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorSpec {
    pub rows: usize,
    pub cols: usize,
    /// Physical [width (u), height (v)], mm.
    pub size_mm: [f64; 2],
    /// In-plane shift [u, v], mm.
    #[serde(default)]
    pub offset_mm: [f64; 2],
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeSpec {
    /// Voxels per axis (cubic grid).
    pub n: usize,
    /// Cube edge, mm.
    pub size_mm: f64,
    /// Grid centre (x, y, z), mm.
    #[serde(default)]
    pub offset_mm: [f64; 3],
}

/// What is scanned.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ObjectSpec {
    /// The built-in analytic spectral phantom, fitted in a cylinder of `radius_mm`, plus optional
    /// `inserts`: ellipsoids in world mm whose material fraction deltas add to the phantom's, e.g.
    /// a metal rod `{ label: iron rod, ellipsoid: { centre: [0, 30, 0], semi_axes: [4, 4, 60] },
    /// materials: [[water, -1.0], [iron, 1.0]] }`.
    Phantom {
        radius_mm: f64,
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        inserts: Vec<Component>,
    },
    /// An HU volume (`.npy`, int16, axes (z, y, x)); `path` is relative to the config file.
    Hu {
        path: PathBuf,
        /// (dz, dy, dx) of the stored array, mm.
        voxel_mm: [f64; 3],
        /// HU → material fractions (thresholds, iodine contrast); documented defaults.
        #[serde(default)]
        mapping: HuMapping,
    },
}

impl GeometrySpec {
    /// The geometry with `views` training angles followed by the test angles.
    pub fn build(&self, seed: u64) -> Result<Geometry> {
        let d = &self.detector;
        let v = &self.volume;
        if self.views == 0 {
            return Err(Error::invalid("views", "must be at least 1"));
        }
        for (field, n) in [
            ("detector.rows", d.rows),
            ("detector.cols", d.cols),
            ("volume.n", v.n),
        ] {
            if n == 0 {
                return Err(Error::invalid(field, "must be at least 1"));
            }
        }
        let mut angles = Geometry::uniform_angles(
            self.views,
            self.start_deg.to_radians(),
            self.total_deg.to_radians(),
        );
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut test: Vec<f64> = (0..self.test_views)
            .map(|_| rng.random::<f64>() * 2.0 * PI)
            .collect();
        test.sort_by(f64::total_cmp);
        angles.extend(test);
        let g = Geometry {
            beam: self.beam,
            dso: self.dso,
            dsd: self.dsd,
            detector: Detector {
                rows: d.rows,
                cols: d.cols,
                pitch_u: d.size_mm[0] / d.cols as f64,
                pitch_v: d.size_mm[1] / d.rows as f64,
                offset_u: d.offset_mm[0],
                offset_v: d.offset_mm[1],
            },
            volume: VolumeGrid {
                offset: v.offset_mm,
                ..VolumeGrid::cube(v.n, v.size_mm / v.n as f64)
            },
            angles_rad: angles,
            vectors: None,
        };
        g.validate()?;
        match &self.disturb {
            Some(d) => d.apply(&g, seed).map_err(|e| e.under("disturb")),
            None => Ok(g),
        }
    }
}

impl SimulateConfig {
    /// The simulation's peak memory, estimated from the config's counts before anything is
    /// built (an upper bound); an error names the count whose arrays could not exist.
    pub fn footprint(&self) -> Result<Footprint> {
        let g = &self.geometry;
        let n = g.volume.n;
        let voxels = memory::elements("geometry.volume.n", &[n, n, n])?;
        let views = g.views.saturating_add(g.test_views);
        let (rows, cols) = (g.detector.rows, g.detector.cols);
        let pixels = memory::elements("geometry.views", &[views, rows, cols])?;
        let materials = self.object.materials_used()?.len();
        let channels = self.channels.len() + usize::from(self.structural.is_some());
        let stack = format!("{views} views × {rows}×{cols}");
        let mut f = Footprint::process();
        f.add(
            format!("material line integrals ({materials} materials × {stack})"),
            memory::bytes(pixels, 4 * materials),
        );
        f.add(
            format!("material fractions ({materials} × {n}³, and the scene's copy)"),
            memory::bytes(voxels, 8 * materials),
        );
        if let ObjectSpec::Hu { path, .. } = &self.object {
            // int16 as stored, and as f32.
            let stored = std::fs::metadata(path).map_or(0, |m| m.len());
            f.add("the HU volume as read and as f32", stored.saturating_mul(3));
            let k = HU_PROJECTION_OVERSAMPLING;
            let fine = memory::elements("geometry.volume.n", &[n * k, n * k, n * k])?;
            f.add(
                format!(
                    "HU → material fractions on the {k}× finer projection grid ({}³, its working \
                     arrays)",
                    n * k
                ),
                memory::bytes(fine, HU_FINE_VOXEL_BYTES),
            );
        }
        f.add(
            format!("projections ({channels} channels × {stack}, and the scene's copy)"),
            memory::bytes(pixels, 8 * channels),
        );
        f.add(
            "one channel's projections while formed (and its noisy training views)",
            memory::bytes(pixels, 8),
        );
        f.add(
            format!(
                "reference volumes ({} × {n}³, and the scene's copy)",
                self.channels.len()
            ),
            memory::bytes(voxels, 8 * self.channels.len()),
        );
        Ok(f)
    }

    /// Read a config file; errors name the file.
    pub fn load(path: &Path) -> Result<Self> {
        Self::load_with(path, &Overrides::default())
    }

    /// Read a config file with `--set` overrides applied; errors name the file (and the override
    /// when an overridden field is wrong). A relative HU volume path is relative to the file.
    pub fn load_with(path: &Path, overrides: &Overrides) -> Result<Self> {
        let mut cfg: SimulateConfig = crate::yaml::read_with(path, overrides)?;
        if let ObjectSpec::Hu { path: p, .. } = &mut cfg.object
            && p.is_relative()
        {
            *p = path.parent().unwrap_or(Path::new(".")).join(&*p);
        }
        Ok(cfg)
    }

    /// The overrides that give the paper's resolution (256³ volume, 512² detector) with every
    /// physical size unchanged (`prism simulate --paper-scale`).
    pub fn paper_scale() -> Overrides {
        Overrides::parse([
            "geometry.volume.n=256",
            "geometry.detector.rows=512",
            "geometry.detector.cols=512",
        ])
        .expect("valid overrides")
    }

    /// Number of training views.
    pub fn train_views(&self) -> usize {
        self.geometry.views
    }
}

/// Oversampling of the grid HU volumes are projected from, relative to the scene grid.
pub const HU_PROJECTION_OVERSAMPLING: usize = 2;
/// Peak bytes per voxel of the finer grid while an HU volume becomes material fractions there
/// and they are projected: the resampled HU, the fractions and the conversion's temporaries.
/// Measured with `/usr/bin/time -v` on head-3mono at 96³ and 128³ (fine grids 192³, 256³:
/// 475.7 and 1019 MB peak) as the slope over what the other items account for: 47.
pub const HU_FINE_VOXEL_BYTES: usize = 47;
/// Point samples per voxel edge when voxelising the analytic phantom's reference volumes.
pub const PHANTOM_SUPERSAMPLING: usize = 3;

/// Material amounts of an object: per-material path lengths `[view][row][col]` (mm) along every
/// pixel ray, and fraction volumes `[z][y][x]` on the scene grid.
pub struct MaterialData {
    pub paths: MaterialVolumes,
    pub fractions: MaterialVolumes,
}

impl ObjectSpec {
    /// The analytic phantom with its inserts (an error for an HU volume); errors name
    /// `object.phantom…`.
    fn phantom(&self) -> Result<SpectralPhantom> {
        let ObjectSpec::Phantom { radius_mm, inserts } = self else {
            return Err(Error::invalid("object", "not an analytic phantom"));
        };
        let mut phantom =
            SpectralPhantom::builtin(*radius_mm).map_err(|e| e.under("object.phantom"))?;
        for (i, insert) in inserts.iter().enumerate() {
            insert
                .validate()
                .map_err(|e| e.under(&format!("object.phantom.inserts[{i}]")))?;
            phantom.ellipsoids.push(insert.clone());
        }
        Ok(phantom)
    }

    /// The materials the object holds, in [`crate::physics::Material::ALL`] order.
    fn materials_used(&self) -> Result<Vec<crate::physics::Material>> {
        match self {
            ObjectSpec::Phantom { .. } => Ok(self.phantom()?.materials()),
            ObjectSpec::Hu { mapping, .. } => Ok(mapping.materials()),
        }
    }

    /// Path lengths along the rays of `geometry` and fractions on its grid.
    pub fn materials(&self, geometry: &Geometry, observer: &dyn Observer) -> Result<MaterialData> {
        match self {
            ObjectSpec::Phantom { .. } => {
                let phantom = self.phantom()?;
                observer.phase("analytic material line integrals", 0);
                let paths = phantom.material_paths(geometry)?;
                observer.phase("voxelising reference fractions", 0);
                let fractions = phantom.fractions(&geometry.volume, PHANTOM_SUPERSAMPLING)?;
                Ok(MaterialData { paths, fractions })
            }
            ObjectSpec::Hu {
                path,
                voxel_mm,
                mapping,
            } => {
                let grid = &geometry.volume;
                let k = HU_PROJECTION_OVERSAMPLING;
                let fine = VolumeGrid {
                    nx: grid.nx * k,
                    ny: grid.ny * k,
                    nz: grid.nz * k,
                    dx: grid.dx / k as f64,
                    dy: grid.dy / k as f64,
                    dz: grid.dz / k as f64,
                    offset: grid.offset,
                };
                observer.phase(&format!("HU → materials on a {k}x finer grid"), 0);
                let fine_fractions = hu_material_volumes(path, *voxel_mm, &fine, mapping)?;
                let projector = Joseph::new(&Geometry {
                    volume: fine,
                    ..geometry.clone()
                })?;
                let mut paths = Vec::with_capacity(fine_fractions.len());
                for (m, f) in fine_fractions {
                    observer.phase(&format!("projecting {}", m.name()), 0);
                    paths.push((m, projector.forward(f.view())?));
                }
                observer.phase("HU → materials on the scene grid", 0);
                let fractions = hu_material_volumes(path, *voxel_mm, grid, mapping)?;
                Ok(MaterialData { paths, fractions })
            }
        }
    }
}

/// The scene-format spectral coordinate of a channel description.
pub fn coordinate_of(spec: &ChannelSpec) -> SpectralCoordinate {
    match *spec {
        ChannelSpec::Mono { kev } => SpectralCoordinate::Energy { kev },
        ChannelSpec::Mixed {
            lambda,
            low_kvp,
            high_kvp,
            ..
        } => SpectralCoordinate::Mixing {
            lambda,
            low_kvp: low_kvp as f64,
            high_kvp: high_kvp as f64,
        },
        ChannelSpec::Polychromatic { kvp, .. } => {
            SpectralCoordinate::TubeVoltage { kvp: kvp as f64 }
        }
        ChannelSpec::Window { lo_kev, hi_kev, .. } => SpectralCoordinate::Window { lo_kev, hi_kev },
    }
}

/// Simulate the scene of a config file with `overrides` applied; the provenance records the
/// file's text and the overrides.
pub fn simulate_file(path: &Path, overrides: &Overrides, observer: &dyn Observer) -> Result<Scene> {
    let cfg = SimulateConfig::load_with(path, overrides)?;
    let mut scene = simulate(&cfg, Some(path), observer)?;
    scene.provenance.overrides = overrides.texts();
    Ok(scene)
}

/// Simulate the scene a config describes. `config_path` (when given) is recorded verbatim in the
/// provenance and named in errors about the config's fields.
pub fn simulate(
    cfg: &SimulateConfig,
    config_path: Option<&Path>,
    observer: &dyn Observer,
) -> Result<Scene> {
    simulate_unnamed(cfg, config_path, observer).map_err(|e| match config_path {
        Some(p) => e.in_file(p),
        None => e,
    })
}

fn simulate_unnamed(
    cfg: &SimulateConfig,
    config_path: Option<&Path>,
    observer: &dyn Observer,
) -> Result<Scene> {
    if cfg.channels.is_empty() {
        return Err(Error::invalid(
            "channels",
            "at least one channel is required",
        ));
    }
    // Counts whose arrays could not exist are refused before anything is built.
    cfg.footprint()?;
    for (i, ch) in cfg.channels.iter().enumerate() {
        ch.validate()
            .map_err(|e| e.under(&format!("channels[{i}]")))?;
    }
    if let Some(noise) = &cfg.noise {
        noise.validate().map_err(|e| e.under("noise"))?;
    }
    let geometry = cfg
        .geometry
        .build(cfg.seed)
        .map_err(|e| e.under("geometry"))?;
    let n_train = cfg.geometry.views;
    let n_views = geometry.views();
    let n_channels = cfg.channels.len();
    let mut channels: Vec<Channel> = cfg
        .channels
        .iter()
        .map(|c| Channel::new(c.label(), coordinate_of(c)))
        .collect();
    normalise_tau(&mut channels)?;
    let mut availability = Array2::from_elem((n_views, n_channels), true);
    for (i, &[view, channel]) in cfg.missing.iter().enumerate() {
        if view >= n_views || channel >= n_channels {
            return Err(Error::invalid(
                format!("missing[{i}]"),
                format!(
                    "(view {view}, channel {channel}) is outside {n_views} views × {n_channels} channels"
                ),
            ));
        }
        availability[[view, channel]] = false;
    }
    if cfg.acquisition.views == ViewSharing::Interleaved {
        for v in 0..n_train {
            for c in 0..n_channels {
                if v % n_channels != c {
                    availability[[v, c]] = false;
                }
            }
        }
    }

    let materials = cfg.object.materials(&geometry, observer)?;
    let noisy = |mut p: Array3<f32>, share: f64, stream: u64| -> Result<Array3<f32>> {
        if let Some(noise) = &cfg.noise {
            // Training views only; test views stay noise-free for evaluation.
            let mut train = p.slice(s![..n_train, .., ..]).to_owned();
            let model = NoiseModel {
                i0: noise.i0 * share,
                ..*noise
            };
            add_noise(&mut train, &model, cfg.seed.wrapping_add(stream))?;
            p.slice_mut(s![..n_train, .., ..]).assign(&train);
        }
        Ok(p)
    };
    let mut projections = Vec::with_capacity(n_channels);
    let mut references = Vec::with_capacity(n_channels);
    for (c, spec) in cfg.channels.iter().enumerate() {
        observer.phase(&format!("channel {}", spec.label()), 0);
        let field = |e: Error| e.under(&format!("channels[{c}]"));
        let share = match cfg.acquisition.photons {
            PhotonSharing::PerChannel => 1.0,
            PhotonSharing::Split => spec.photon_share().map_err(field)?,
        };
        let mut p = noisy(
            spec.project(&materials.paths).map_err(field)?,
            share,
            1 + c as u64,
        )?;
        for v in 0..n_views {
            if !availability[[v, c]] {
                p.index_axis_mut(Axis(0), v).fill(0.0);
            }
        }
        projections.push(p);
        references.push(spec.volume(&materials.fractions).map_err(field)?);
    }
    let structural = match &cfg.structural {
        Some(spec) => {
            spec.validate().map_err(|e| e.under("structural"))?;
            Some(noisy(
                spec.project(&materials.paths)?,
                1.0,
                1 + n_channels as u64,
            )?)
        }
        None => None,
    };

    let mut provenance = Provenance {
        generator: format!("prism simulate {}", env!("CARGO_PKG_VERSION")),
        config: match config_path {
            Some(p) => std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?,
            None => serde_yaml_ng::to_string(cfg)
                .map_err(|e| Error::invalid("config", e.to_string()))?,
        },
        ..Provenance::default()
    };
    match &cfg.object {
        ObjectSpec::Phantom { radius_mm, inserts } => provenance.source_data.push(format!(
            "built-in analytic spectral phantom, radius {radius_mm} mm, {} insert(s)",
            inserts.len()
        )),
        ObjectSpec::Hu { path, .. } => {
            provenance.source_data.push(path.display().to_string());
            provenance.licence.push(
                "CT volume from The Cancer Imaging Archive (TCIA), CC BY 3.0 and the TCIA data usage \
                 policy; DICOM-to-volume selection from XCIST phantoms-voxelized (BSD-3). Acknowledge TCIA \
                 wherever results on it are shown."
                    .into(),
            );
        }
    }
    provenance.licence.push(
        "Attenuation: NIST (public domain) via xraydb/Elam (BSD); spectra: SpekPy (MIT).".into(),
    );

    let scene = Scene {
        name: cfg.name.clone(),
        geometry,
        channels,
        projections: stack(&projections),
        availability,
        references: Some(stack(&references)),
        split: Split {
            train: (0..n_train).collect(),
            test: (n_train..n_views).collect(),
        },
        provenance,
        structural,
        materials: Some(MaterialMaps {
            materials: materials.fractions.iter().map(|(m, _)| *m).collect(),
            fractions: stack(
                &materials
                    .fractions
                    .into_iter()
                    .map(|(_, f)| f)
                    .collect::<Vec<_>>(),
            ),
        }),
    };
    scene.validate()?;
    Ok(scene)
}

/// Stack per-channel 3D arrays into `[channel][..]`.
fn stack(arrays: &[Array3<f32>]) -> Array4<f32> {
    let views: Vec<_> = arrays.iter().map(|a| a.view()).collect();
    ndarray::stack(Axis(0), &views).expect("channel arrays share one shape")
}

#[cfg(test)]
mod tests;
