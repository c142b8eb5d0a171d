//! The import config (`prism import <import.yaml>`): where the measured images are, what they
//! are, the scanner geometry and the view selection. See `docs/import.md` for the format.

use super::fan::Rebinning;
pub use super::fan::{FanDetector, FanGeometry};
use crate::geometry::{Beam, Detector, Geometry, TigreGeometry, ViewVectors, VolumeGrid};
use crate::scene::SpectralCoordinate;
use crate::{Error, Result};
use serde::Deserialize;
use std::f64::consts::PI;
use std::path::PathBuf;

/// A measured scan: one or several acquisitions (kVp settings, energy windows) of one object.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImportConfig {
    pub name: String,
    /// The scanner without its angles: Prism's own fields (`docs/geometry.md`) or TIGRE's.
    #[serde(with = "serde_yaml_ng::with::singleton_map")]
    pub geometry: GeometrySource,
    /// The angles of the full scan, one per image of a full stack (optional with `vectors`,
    /// which imply them).
    #[serde(default)]
    pub angles: AngleSpec,
    /// The rotation axis: `given` (the geometry's `offset_u`, the default), or estimated from
    /// the projections and written into the scene's geometry: `auto`, `opposing`, `sharpness`,
    /// or `{method: …, range_px: …}` (`docs/import.md`, "Rotation axis").
    #[serde(default)]
    pub axis: super::AxisConfig,
    /// Images stored with the bottom detector row first (TIGRE's order); Prism's row 0 is the
    /// top (+z). TIGRE geometries imply it.
    #[serde(default)]
    pub rows_bottom_up: bool,
    /// Flat (open beam) and dark fields of every channel that gives none of its own:
    /// `[rows, cols]` or a stack `[n, rows, cols]` (averaged).
    #[serde(default)]
    pub flat: Option<ImageSource>,
    #[serde(default)]
    pub dark: Option<ImageSource>,
    /// Dark-corrected counts `I − D` below this are raised to it before the log, so zero and
    /// negative counts give a large but finite line integral (default 0.5 counts). How many
    /// pixels were raised is reported.
    #[serde(default = "default_min_counts")]
    pub min_counts: f64,
    /// Ring suppression on every channel (`{size: 21}`: sorting-based stripe removal), before
    /// the log for counts (`import::rings`); none by default.
    #[serde(default)]
    pub rings: Option<super::rings::RingConfig>,
    /// Bad-pixel repair on every channel given as counts (`{}`: pixels whose open beam is not
    /// positive or deviates from its neighbours' median by more than half; `import::bad_pixels`),
    /// before the log; none by default.
    #[serde(default)]
    pub bad_pixels: Option<super::bad_pixels::BadPixelConfig>,
    /// Set negative line integrals (rays through air whose noise read more than the open beam)
    /// to zero, after the log and the repairs, in every channel; how many is reported. Off by
    /// default: clipping keeps only the positive half of the air's noise and biases it upwards.
    /// Some published pipelines clip (Cueva et al.'s bird data, `configs/real/bird-dtv.yaml`).
    #[serde(default)]
    pub clip_negative: bool,
    pub channels: Vec<ChannelSource>,
    #[serde(default)]
    pub select: ViewSelection,
    /// Where the data come from, and licence or acknowledgement lines that travel with them.
    #[serde(default)]
    pub source_data: Vec<String>,
    #[serde(default)]
    pub licence: Vec<String>,
}

fn default_min_counts() -> f64 {
    0.5
}

/// The scanner geometry, without angles.
#[derive(Clone, Debug, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum GeometrySource {
    Prism {
        beam: Beam,
        dso: f64,
        dsd: f64,
        detector: Detector,
        volume: VolumeGrid,
    },
    /// TIGRE's Python fields in TIGRE's orders (`(v, u)`, `(z, y, x)`).
    Tigre(TigreGeometry),
    /// A 2-D fan beam on a flat detector line: one slice (`docs/geometry.md`).
    Fan(FanGeometry),
    /// Every view's pose given as a row of vectors (ASTRA's `cone_vec`, `parallel3d_vec` or
    /// `fanflat_vec`).
    Vectors(VectorGeometry),
}

/// A scan given by per-view vectors: `file` holds one row per view of the full scan, in ASTRA's
/// layout (`docs/geometry.md`, "Per-view vectors"): 12 numbers `(source or ray, detector
/// centre, u, v)` for `cone` and `parallel`, 6 numbers `(source, detector centre, u)` in the
/// plane z = 0 for `fan` (stored as the middle row of a cone beam, as [`FanGeometry`]).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VectorGeometry {
    pub beam: VectorBeam,
    /// `.npy` (`[views, 12]` or `[views, 6]`, f64 or f32), text (one row per line, numbers
    /// separated by spaces or commas, `#` comments) or HDF5 / MATLAB -v7.3 (`dataset`);
    /// relative to the import config.
    pub file: PathBuf,
    /// The dataset of an HDF5 / MATLAB -v7.3 `file` (e.g. `/geometry/vectors`).
    #[serde(default)]
    pub dataset: Option<String>,
    /// How that dataset is stored: `theta:x` (views first, the default) or `x:theta` (a MATLAB
    /// views × 12 matrix, which -v7.3 stores column-major).
    #[serde(default)]
    pub axes: Option<String>,
    /// Detector rows (a fan has one) and columns.
    pub rows: Option<usize>,
    pub cols: usize,
    /// The volume grid, mm. A fan's has `nz = 1` and `dz` the slice's thickness (no ray leaves
    /// the plane z = 0; the row height at the axis is the usual choice).
    pub volume: VolumeGrid,
}

/// The beam of a [`VectorGeometry`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VectorBeam {
    Cone,
    Parallel,
    Fan,
}

impl VectorGeometry {
    /// Numbers in a row of the file.
    pub fn row_len(&self) -> usize {
        match self.beam {
            VectorBeam::Fan => 6,
            _ => 12,
        }
    }

    /// The geometry of `rows` (read from `file`), with the config's `angles` if it gives any.
    pub fn to_geometry(&self, rows: &[Vec<f64>], angles: Option<Vec<f64>>) -> Result<Geometry> {
        let width = self.row_len();
        if let Some(k) = rows.iter().position(|r| r.len() != width) {
            return Err(Error::invalid(
                format!("file row {k}"),
                format!(
                    "holds {} numbers; a {:?} row has {width}",
                    rows[k].len(),
                    self.beam
                ),
            ));
        }
        let (beam, det_rows) = match self.beam {
            VectorBeam::Cone => (Beam::Cone, self.rows),
            VectorBeam::Parallel => (Beam::Parallel, self.rows),
            VectorBeam::Fan => {
                if self.rows.is_some_and(|r| r != 1) || self.volume.nz != 1 {
                    return Err(Error::invalid(
                        "volume.nz",
                        "a fan beam reconstructs one slice: one detector row, nz = 1",
                    ));
                }
                (Beam::Cone, Some(1))
            }
        };
        let det_rows =
            det_rows.ok_or_else(|| Error::invalid("rows", "give the detector's row count"))?;
        let vectors: Vec<ViewVectors> = rows
            .iter()
            .map(|r| match self.beam {
                VectorBeam::Fan => {
                    let row: [f64; 6] = r[..].try_into().expect("checked width");
                    // The row as high as a column is wide.
                    let pitch = (row[4] * row[4] + row[5] * row[5]).sqrt();
                    ViewVectors::from_fan(row, pitch)
                }
                _ => ViewVectors::from(<[f64; 12]>::try_from(&r[..]).expect("checked width")),
            })
            .collect();
        Geometry::from_vectors(
            beam,
            det_rows,
            self.cols,
            self.volume.clone(),
            vectors,
            angles,
        )
    }
}

/// The full scan's angles: evenly spaced (`count`, `start_deg`, `span_deg`), listed (`deg`), or
/// read from a file (`file`, `.npy` or text with one value per line, in `unit`).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AngleSpec {
    pub count: Option<usize>,
    #[serde(default)]
    pub start_deg: f64,
    /// Default a full turn; the endpoint is excluded.
    pub span_deg: Option<f64>,
    pub deg: Option<Vec<f64>>,
    pub file: Option<PathBuf>,
    /// The dataset holding the angles when `file` is HDF5 (`/exchange/theta`).
    pub dataset: Option<String>,
    pub unit: Option<AngleUnit>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AngleUnit {
    Deg,
    Rad,
}

/// One acquisition: a channel of the scene.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSource {
    pub label: String,
    pub coordinate: SpectralCoordinate,
    /// Raw counts `[views, rows, cols]`: line integrals −ln((I − D)/(F − D)).
    pub counts: Option<ImageSource>,
    /// Or line integrals already (`[views, rows, cols]`, e.g. another tool's output).
    pub line_integrals: Option<ImageSource>,
    /// This channel's own flat and dark fields (else the config's).
    pub flat: Option<ImageSource>,
    pub dark: Option<ImageSource>,
    /// The views of the full scan this channel's images were taken at, in stack order (default:
    /// all of them); the other views are marked unavailable for it.
    pub views: Option<Vec<usize>>,
    /// This channel's reference recon config, overriding `select.reference` (a regulariser
    /// weight suited to its noise).
    pub reference: Option<PathBuf>,
    /// Or this channel's reference as a volume made elsewhere (a published reconstruction):
    /// images `[nz, ny, nx]` on the scene's grid, in Prism's axes (`docs/geometry.md`), μ in
    /// mm⁻¹. Overrides `select.reference` like `reference`.
    pub reference_volume: Option<ImageSource>,
}

/// Images: a file holding a stack (`.npy`, `.tif`/`.tiff`, a `dataset` of an HDF5 or MATLAB
/// v7.3 file, or headerless with `raw`), or a directory of one image per view (`.npy` or
/// `.tif`, in file-name order).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageSource {
    pub path: PathBuf,
    pub raw: Option<RawLayout>,
    /// HDF5: the dataset's path in the file (`/exchange/data`, `/CtData/sinogram`).
    pub dataset: Option<String>,
    /// HDF5: the stored axis order, `:`-separated names of `theta` (views or frames), `y`
    /// (detector rows) and `x` (columns), when the dataset has no `axes` attribute and is not
    /// `theta:y:x` (MATLAB stores column-major: a `views × cols` sinogram is `x:theta`).
    pub axes: Option<String>,
}

/// A headerless file: element type, shape (`[views, rows, cols]` or `[rows, cols]`), byte
/// order and bytes to skip before the data.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawLayout {
    pub dtype: RawType,
    pub shape: Vec<usize>,
    #[serde(default)]
    pub big_endian: bool,
    #[serde(default)]
    pub header_bytes: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RawType {
    U8,
    U16,
    U32,
    I16,
    I32,
    F32,
    F64,
}

impl RawType {
    pub fn size(self) -> usize {
        match self {
            RawType::U8 => 1,
            RawType::U16 | RawType::I16 => 2,
            RawType::U32 | RawType::I32 | RawType::F32 => 4,
            RawType::F64 => 8,
        }
    }
}

/// Which views of the full scan the scene keeps.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewSelection {
    /// Training views: this many, evenly over the scan (view ⌊i·n/count⌋), or every `every`-th
    /// from view 0; default every view.
    pub views: Option<usize>,
    pub every: Option<usize>,
    /// Test views (projection metrics), evenly among the views not used for training.
    #[serde(default)]
    pub test_views: usize,
    /// Reference volumes, each channel reconstructed from every view it was measured at:
    /// `fdk` (as the paper's real data use), `{recon: classic.yaml}` (a classic method's config,
    /// e.g. non-negative TV; a channel's own `reference` overrides it), or `none`.
    #[serde(default, with = "serde_yaml_ng::with::singleton_map")]
    pub reference: ReferenceKind,
}

#[derive(Clone, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReferenceKind {
    #[default]
    Fdk,
    /// A classic recon config (`configs/recon/*.yaml`, path relative to the import config).
    Recon(PathBuf),
    None,
}

impl ImportConfig {
    /// The geometry with the full scan's angles (radians; `None` when the config gives none,
    /// which only vectors allow), the vector rows when the geometry is given by vectors, and
    /// whether stored rows run bottom-up.
    pub fn geometry(
        &self,
        angles_rad: Option<Vec<f64>>,
        vector_rows: Option<&[Vec<f64>]>,
    ) -> Result<(Geometry, bool)> {
        if let GeometrySource::Vectors(v) = &self.geometry {
            let rows =
                vector_rows.ok_or_else(|| Error::invalid("geometry.vectors.file", "not read"))?;
            let g = v
                .to_geometry(rows, angles_rad)
                .map_err(|e| e.under("geometry.vectors"))?;
            return Ok((g, self.rows_bottom_up));
        }
        let angles_rad = angles_rad.ok_or_else(|| {
            Error::invalid(
                "angles",
                "give exactly one of `count` (evenly spaced), `deg` (a list) or `file`",
            )
        })?;
        match &self.geometry {
            GeometrySource::Prism {
                beam,
                dso,
                dsd,
                detector,
                volume,
            } => {
                let g = Geometry {
                    beam: *beam,
                    dso: *dso,
                    dsd: *dsd,
                    detector: detector.clone(),
                    volume: volume.clone(),
                    angles_rad,
                    vectors: None,
                };
                g.validate().map_err(|e| e.under("geometry.prism"))?;
                Ok((g, self.rows_bottom_up))
            }
            GeometrySource::Tigre(t) => Ok((
                t.to_geometry(angles_rad)
                    .map_err(|e| e.under("geometry.tigre"))?,
                true,
            )),
            GeometrySource::Fan(f) => Ok((
                f.to_geometry(angles_rad)
                    .map_err(|e| e.under("geometry.fan"))?,
                self.rows_bottom_up,
            )),
            GeometrySource::Vectors(_) => unreachable!("handled above"),
        }
    }

    /// How the measured detector columns become the scene's: `Some` for a curved fan detector
    /// (rebinned onto a flat line), `None` when they are the scene's own.
    pub fn rebinning(&self) -> Result<Option<Rebinning>> {
        match &self.geometry {
            GeometrySource::Fan(f) => f.rebinning().map_err(|e| e.under("geometry.fan")),
            _ => Ok(None),
        }
    }

    /// Training and test views (sorted indices into the full scan of `n` views).
    pub fn pick_views(&self, n: usize) -> Result<(Vec<usize>, Vec<usize>)> {
        let s = &self.select;
        let train: Vec<usize> = match (s.views, s.every) {
            (Some(_), Some(_)) => {
                return Err(Error::invalid(
                    "select",
                    "give `views` or `every`, not both",
                ));
            }
            (Some(k), None) => {
                if k == 0 || k > n {
                    return Err(Error::invalid(
                        "select.views",
                        format!("must be between 1 and the scan's {n} views, got {k}"),
                    ));
                }
                (0..k).map(|i| i * n / k).collect()
            }
            (None, Some(e)) => {
                if e == 0 {
                    return Err(Error::invalid("select.every", "must be at least 1"));
                }
                (0..n).step_by(e).collect()
            }
            (None, None) => (0..n).collect(),
        };
        let rest: Vec<usize> = (0..n).filter(|v| train.binary_search(v).is_err()).collect();
        let t = s.test_views;
        if t > rest.len() {
            return Err(Error::invalid(
                "select.test_views",
                format!(
                    "{t} test views asked, but only {} views are not used for training",
                    rest.len()
                ),
            ));
        }
        let test = (0..t).map(|i| rest[i * rest.len() / t]).collect();
        Ok((train, test))
    }
}

/// Refuse an angle `count` whose angles and one f32 per view already exceed the memory
/// available, before any is made (a count of 10¹² would abort the process, even in a
/// `--dry-run`); the full estimate, with the detector, follows in `import::footprint`.
fn check_view_count(n: usize) -> Result<()> {
    let need = crate::memory::bytes(n, 12);
    match crate::memory::exceeds_available(need) {
        Some(a) => Err(Error::invalid(
            "angles.count",
            format!(
                "{n} views need {} for their angles alone; {} is available",
                crate::memory::human(need),
                crate::memory::human(a)
            ),
        )),
        _ => Ok(()),
    }
}

impl AngleSpec {
    /// Whether the config gives angles at all (`count`, `deg` or `file`).
    pub fn is_given(&self) -> bool {
        self.count.is_some() || self.deg.is_some() || self.file.is_some()
    }

    /// The angles in radians (`read` reads a file of values; paths are the caller's concern).
    pub fn resolve(&self, read: impl Fn(&std::path::Path) -> Result<Vec<f64>>) -> Result<Vec<f64>> {
        let given = [
            self.count.is_some(),
            self.deg.is_some(),
            self.file.is_some(),
        ];
        if self.dataset.is_some() && self.file.is_none() {
            return Err(Error::invalid(
                "angles.dataset",
                "names a dataset of the angle `file`, which is not given",
            ));
        }
        if given.iter().filter(|&&g| g).count() != 1 {
            return Err(Error::invalid(
                "angles",
                "give exactly one of `count` (evenly spaced), `deg` (a list) or `file`",
            ));
        }
        let angles = if let Some(n) = self.count {
            check_view_count(n)?;
            let span = self.span_deg.unwrap_or(360.0);
            Geometry::uniform_angles(n, self.start_deg.to_radians(), span.to_radians())
        } else if let Some(d) = &self.deg {
            d.iter().map(|a| a.to_radians()).collect()
        } else {
            let file = self.file.as_deref().unwrap_or(std::path::Path::new(""));
            let values = read(file)?;
            match self.unit {
                Some(AngleUnit::Deg) => values.iter().map(|a| a.to_radians()).collect(),
                Some(AngleUnit::Rad) => values,
                None => {
                    return Err(Error::invalid(
                        "angles.unit",
                        "say whether the file's angles are in `deg` or `rad`",
                    ));
                }
            }
        };
        if angles.is_empty() {
            return Err(Error::invalid("angles", "no angles"));
        }
        if let Some(i) = angles.iter().position(|a| !a.is_finite()) {
            return Err(Error::invalid(format!("angles[{i}]"), "is not finite"));
        }
        if angles.iter().any(|a| a.abs() > 16.0 * PI) && self.unit == Some(AngleUnit::Rad) {
            return Err(Error::invalid(
                "angles.unit",
                "angles beyond ±8 turns: are they degrees?",
            ));
        }
        Ok(angles)
    }
}
