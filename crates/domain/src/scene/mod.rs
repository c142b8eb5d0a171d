//! Spectral scenes: several energy channels of one object scanned with one [`Geometry`], the
//! measured projections, which (view, channel) pairs were measured, optional reference volumes,
//! the train/test split of the views and where the data came from.
//!
//! Conventions (see `docs/scene-format.md` for the on-disk form):
//!
//! * projections are line integrals ∫μ dl (dimensionless), stored `[channel][view][row][col]`;
//! * `availability[[view, channel]]` is true when that channel was measured at that view; the
//!   projections of unavailable pairs are ignored (by convention they hold 0);
//! * reference volumes are μ in mm⁻¹, stored `[channel][z][y][x]` on `geometry.volume`;
//! * channels are ordered along the spectral axis (strictly increasing
//!   [`SpectralCoordinate::value`]) and carry τ ∈ [0, 1], the coordinate normalised over the scene.

mod axis;
mod gains;
pub(crate) mod io;
pub mod npy;
mod r2;
mod summary;

pub use axis::{AxisEstimate, AxisMethod};
pub use io::{FORMAT_VERSION, SCENE_FILE};
pub use r2::R2_META_FILE;

use crate::geometry::Geometry;
use crate::{Error, Result};
use ndarray::{Array2, Array3, Array4, ArrayView3, Axis};
use serde::{Deserialize, Serialize};

/// The physical spectral coordinate of a channel. Serialised with a `kind` tag, e.g.
/// `{kind: tube_voltage, kvp: 80}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SpectralCoordinate {
    /// A monoenergetic channel at `kev` keV.
    Energy { kev: f64 },
    /// A polychromatic tube spectrum at `kvp` kVp.
    TubeVoltage { kvp: f64 },
    /// A photon-counting energy bin `[lo_kev, hi_kev)`, keV.
    Window { lo_kev: f64, hi_kev: f64 },
    /// A blend `λ·low + (1 − λ)·high` of two tube-voltage channels (kVp), as in the paper.
    Mixing {
        lambda: f64,
        low_kvp: f64,
        high_kvp: f64,
    },
    /// The source gives no spectral coordinate (e.g. an imported single-channel R²-Gaussian
    /// case). Only allowed in a one-channel scene.
    Unspecified,
}

impl SpectralCoordinate {
    /// The scalar that orders channels along the spectral axis: keV (`Energy`), kVp
    /// (`TubeVoltage`), the lower edge in keV (`Window`), λ (`Mixing`); 0 for `Unspecified`.
    pub fn value(&self) -> f64 {
        match *self {
            SpectralCoordinate::Energy { kev } => kev,
            SpectralCoordinate::TubeVoltage { kvp } => kvp,
            SpectralCoordinate::Window { lo_kev, .. } => lo_kev,
            SpectralCoordinate::Mixing { lambda, .. } => lambda,
            SpectralCoordinate::Unspecified => 0.0,
        }
    }

    /// Unit of [`value`](Self::value): `"keV"`, `"kVp"`, `"λ"` (dimensionless) or `""`.
    pub fn unit(&self) -> &'static str {
        match self {
            SpectralCoordinate::Energy { .. } | SpectralCoordinate::Window { .. } => "keV",
            SpectralCoordinate::TubeVoltage { .. } => "kVp",
            SpectralCoordinate::Mixing { .. } => "λ",
            SpectralCoordinate::Unspecified => "",
        }
    }

    /// The serialised `kind` tag (`energy`, `tube_voltage`, `window`, `mixing`, `unspecified`).
    pub fn kind(&self) -> &'static str {
        match self {
            SpectralCoordinate::Energy { .. } => "energy",
            SpectralCoordinate::TubeVoltage { .. } => "tube_voltage",
            SpectralCoordinate::Window { .. } => "window",
            SpectralCoordinate::Mixing { .. } => "mixing",
            SpectralCoordinate::Unspecified => "unspecified",
        }
    }

    /// Check the fields' own ranges (positive energies and voltages, ordered window edges).
    /// Errors name the field relative to the coordinate (`kev`, `hi_kev`…).
    pub fn validate(&self) -> Result<()> {
        use crate::error::ensure_positive as positive;
        match *self {
            SpectralCoordinate::Energy { kev } => positive("kev", kev),
            SpectralCoordinate::TubeVoltage { kvp } => positive("kvp", kvp),
            SpectralCoordinate::Window { lo_kev, hi_kev } => {
                if !(lo_kev.is_finite() && lo_kev >= 0.0) {
                    return Err(Error::invalid(
                        "lo_kev",
                        format!("must be finite and non-negative (got {lo_kev})"),
                    ));
                }
                if !(hi_kev.is_finite() && hi_kev > lo_kev) {
                    return Err(Error::invalid(
                        "hi_kev",
                        format!("must be finite and above lo_kev = {lo_kev} (got {hi_kev})"),
                    ));
                }
                Ok(())
            }
            SpectralCoordinate::Mixing {
                lambda,
                low_kvp,
                high_kvp,
            } => {
                crate::error::ensure_finite("lambda", lambda)?;
                positive("low_kvp", low_kvp)?;
                positive("high_kvp", high_kvp)?;
                if high_kvp <= low_kvp {
                    return Err(Error::invalid(
                        "high_kvp",
                        format!("must exceed low_kvp = {low_kvp} (got {high_kvp})"),
                    ));
                }
                Ok(())
            }
            SpectralCoordinate::Unspecified => Ok(()),
        }
    }

    /// True when two coordinates lie on the same spectral axis (same kind; same kVp pair for
    /// `Mixing`), so that their values can be compared.
    fn same_axis(&self, other: &SpectralCoordinate) -> bool {
        match (self, other) {
            (
                SpectralCoordinate::Mixing {
                    low_kvp: a,
                    high_kvp: b,
                    ..
                },
                SpectralCoordinate::Mixing {
                    low_kvp: c,
                    high_kvp: d,
                    ..
                },
            ) => a == c && b == d,
            _ => self.kind() == other.kind(),
        }
    }
}

impl std::fmt::Display for SpectralCoordinate {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match *self {
            SpectralCoordinate::Energy { kev } => write!(f, "{kev} keV"),
            SpectralCoordinate::TubeVoltage { kvp } => write!(f, "{kvp} kVp"),
            SpectralCoordinate::Window { lo_kev, hi_kev } => write!(f, "[{lo_kev}, {hi_kev}) keV"),
            SpectralCoordinate::Mixing {
                lambda,
                low_kvp,
                high_kvp,
            } => write!(f, "λ = {lambda} ({low_kvp}/{high_kvp} kVp)"),
            SpectralCoordinate::Unspecified => write!(f, "unspecified"),
        }
    }
}

/// One spectral channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Channel {
    /// Short name, unique within the scene (e.g. `"80kVp"`, `"bin2"`).
    pub label: String,
    pub coordinate: SpectralCoordinate,
    /// The coordinate normalised over the scene's channels, in [0, 1]; see [`normalise_tau`].
    pub tau: f64,
}

impl Channel {
    /// A channel with τ = 0 (call [`normalise_tau`] once all channels are known).
    pub fn new(label: impl Into<String>, coordinate: SpectralCoordinate) -> Self {
        Channel {
            label: label.into(),
            coordinate,
            tau: 0.0,
        }
    }
}

/// Check the channel list (non-empty, unique labels, valid coordinates on one spectral axis,
/// strictly increasing values) and return the values' (min, max).
fn check_channel_order(channels: &[Channel]) -> Result<(f64, f64)> {
    let first = channels
        .first()
        .ok_or_else(|| Error::invalid("channels", "a scene needs at least one channel"))?;
    for (i, ch) in channels.iter().enumerate() {
        let field = format!("channels[{i}].coordinate");
        if ch.label.trim().is_empty() {
            return Err(Error::invalid(format!("channels[{i}].label"), "is empty"));
        }
        if let Some(j) = channels[..i].iter().position(|c| c.label == ch.label) {
            return Err(Error::invalid(
                format!("channels[{i}].label"),
                format!("`{}` is also the label of channels[{j}]", ch.label),
            ));
        }
        ch.coordinate.validate().map_err(|e| e.under(&field))?;
        if channels.len() > 1 && ch.coordinate == SpectralCoordinate::Unspecified {
            return Err(Error::invalid(
                field,
                "`unspecified` is only allowed in a one-channel scene",
            ));
        }
        if !ch.coordinate.same_axis(&first.coordinate) {
            return Err(Error::invalid(
                field,
                format!(
                    "{} is not on the spectral axis of channels[0] ({}); all channels must share \
                     one coordinate kind",
                    ch.coordinate, first.coordinate
                ),
            ));
        }
        if i > 0 {
            let prev = channels[i - 1].coordinate.value();
            if ch.coordinate.value() <= prev {
                return Err(Error::invalid(
                    field,
                    format!(
                        "channels must be ordered along the spectral axis (strictly increasing): \
                         {} does not exceed {} {} of channels[{}]",
                        ch.coordinate.value(),
                        prev,
                        ch.coordinate.unit(),
                        i - 1
                    ),
                ));
            }
        }
    }
    let lo = first.coordinate.value();
    let hi = channels[channels.len() - 1].coordinate.value();
    Ok((lo, hi))
}

fn tau_of(v: f64, lo: f64, hi: f64) -> f64 {
    if hi > lo { (v - lo) / (hi - lo) } else { 0.0 }
}

/// Set every channel's τ = (v − min)/(max − min) over the channels (0 for a single channel).
/// The channels must be ordered along the spectral axis; errors name `channels[i].coordinate`.
pub fn normalise_tau(channels: &mut [Channel]) -> Result<()> {
    let (lo, hi) = check_channel_order(channels)?;
    for ch in channels.iter_mut() {
        ch.tau = tau_of(ch.coordinate.value(), lo, hi);
    }
    Ok(())
}

/// Train/test split of the views (indices into the geometry's angle list).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Split {
    pub train: Vec<usize>,
    #[serde(default)]
    pub test: Vec<usize>,
}

impl Split {
    /// All `views` for training, none for testing.
    pub fn all_train(views: usize) -> Self {
        Split {
            train: (0..views).collect(),
            test: Vec::new(),
        }
    }
}

/// Where a scene came from. Free-form text; every field may be empty.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Provenance {
    /// The program (and version) that produced the scene, e.g. `"prism simulate 0.1.0"`.
    pub generator: String,
    /// The configuration text it ran with (verbatim).
    pub config: String,
    /// `--set key=value` overrides applied on top of `config`, in order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub overrides: Vec<String>,
    /// Source data sets or files (e.g. a TCIA collection, an R²-Gaussian case folder).
    pub source_data: Vec<String>,
    /// Licence and acknowledgement lines that must travel with the data.
    pub licence: Vec<String>,
    /// Person or pipeline that created the scene, and when.
    pub created_by: String,
    /// The rotation axis, when the import estimated it (the geometry holds the value used).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axis: Option<AxisEstimate>,
}

/// The material volume fractions of a simulated scene's object on its grid: the truth behind
/// its reference volumes (channel c's is `Σ_m μ̄_m(c)·f_m`), and behind any energy's
/// monoenergetic image `Σ_m μ_m(E)·f_m`.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialMaps {
    pub materials: Vec<crate::physics::Material>,
    /// `[material][z][y][x]`: volume fractions at each material's nominal density.
    pub fractions: Array4<f32>,
}

/// A spectral CT scan of one object. See the module documentation for the conventions.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub name: String,
    pub geometry: Geometry,
    /// Ordered along the spectral axis, τ normalised.
    pub channels: Vec<Channel>,
    /// Line integrals, `[channel][view][row][col]`.
    pub projections: Array4<f32>,
    /// `[view][channel]`: true when that channel was measured at that view.
    pub availability: Array2<bool>,
    /// Reference μ volumes in mm⁻¹, `[channel][z][y][x]` on `geometry.volume`.
    pub references: Option<Array4<f32>>,
    pub split: Split,
    pub provenance: Provenance,
    /// An optional measured full-spectrum (all photons) projection, `[view][row][col]`, line
    /// integrals (photon-counting scanners provide it).
    pub structural: Option<Array3<f32>>,
    /// The object's material fractions, when the scene was simulated.
    pub materials: Option<MaterialMaps>,
}

impl Scene {
    /// Number of channels.
    pub fn n_channels(&self) -> usize {
        self.channels.len()
    }

    /// Number of views.
    pub fn n_views(&self) -> usize {
        self.geometry.views()
    }

    /// Reference volume of channel `c`, `[z][y][x]` in mm⁻¹, if the scene has references.
    /// Panics if `c` is out of range.
    pub fn reference(&self, c: usize) -> Option<ArrayView3<'_, f32>> {
        self.references.as_ref().map(|r| r.index_axis(Axis(0), c))
    }

    /// Projections of channel `c`, `[view][row][col]`. Panics if `c` is out of range.
    pub fn channel_projections(&self, c: usize) -> ArrayView3<'_, f32> {
        self.projections.index_axis(Axis(0), c)
    }

    /// Channels measured at `view`, in channel order. Panics if `view` is out of range.
    pub fn available_channels(&self, view: usize) -> Vec<usize> {
        let row = self.availability.row(view);
        (0..row.len()).filter(|&c| row[c]).collect()
    }

    /// Views (all, train and test) at which channel `c` was measured, increasing.
    pub fn views_with_channel(&self, c: usize) -> Vec<usize> {
        let col = self.availability.column(c);
        (0..col.len()).filter(|&v| col[v]).collect()
    }

    /// The training views, in split order.
    pub fn train_views(&self) -> &[usize] {
        &self.split.train
    }

    /// The held-out test views, in split order.
    pub fn test_views(&self) -> &[usize] {
        &self.split.test
    }

    /// The training views at which each channel was measured (`split.train` ∩ availability);
    /// an error names a channel without any.
    pub fn channel_training_views(&self) -> Result<Vec<Vec<usize>>> {
        let mut out = Vec::new();
        for (c, ch) in self.channels.iter().enumerate() {
            let views: Vec<usize> = self
                .train_views()
                .iter()
                .copied()
                .filter(|&v| self.availability[[v, c]])
                .collect();
            if views.is_empty() {
                return Err(Error::invalid(
                    "availability",
                    format!("channel `{}` has no available training view", ch.label),
                ));
            }
            out.push(views);
        }
        Ok(out)
    }

    /// The scene without the listed channels (the others keep their τ), e.g. without the
    /// channels held out of training.
    pub fn without_channels(&self, drop: &[usize]) -> Scene {
        let keep: Vec<usize> = (0..self.n_channels())
            .filter(|c| !drop.contains(c))
            .collect();
        Scene {
            name: self.name.clone(),
            geometry: self.geometry.clone(),
            channels: keep.iter().map(|&c| self.channels[c].clone()).collect(),
            projections: self.projections.select(Axis(0), &keep),
            availability: self.availability.select(Axis(1), &keep),
            references: self.references.as_ref().map(|r| r.select(Axis(0), &keep)),
            split: self.split.clone(),
            provenance: self.provenance.clone(),
            structural: self.structural.clone(),
            materials: self.materials.clone(),
        }
    }

    /// Check everything: geometry, channels, split, every array's shape against the geometry and
    /// its values (finite). Errors name the field (`geometry.dso`, `channels[1].coordinate`,
    /// `split.test[0]`, `projections[2][0][3][4]`…).
    pub fn validate(&self) -> Result<()> {
        self.check_metadata()?;
        self.check_projections()?;
        self.check_availability()?;
        self.check_references()?;
        self.check_structural()?;
        self.check_materials()
    }

    /// Geometry, channels (order, τ) and split; nothing that needs the arrays.
    fn check_metadata(&self) -> Result<()> {
        check_metadata(&self.geometry, &self.channels, &self.split)
    }

    fn expected_projection_shape(&self) -> [usize; 4] {
        let d = &self.geometry.detector;
        [self.n_channels(), self.n_views(), d.rows, d.cols]
    }

    fn expected_reference_shape(&self) -> [usize; 4] {
        let [z, y, x] = self.geometry.volume.shape_zyx();
        [self.n_channels(), z, y, x]
    }

    fn check_projections(&self) -> Result<()> {
        check_shape(
            "projections",
            self.projections.shape(),
            &self.expected_projection_shape(),
        )?;
        check_finite("projections", self.projections.view().into_dyn(), |i| {
            format!("channel `{}`", self.channels[i[0]].label)
        })
    }

    fn check_availability(&self) -> Result<()> {
        check_shape(
            "availability",
            self.availability.shape(),
            &[self.n_views(), self.n_channels()],
        )?;
        for (c, ch) in self.channels.iter().enumerate() {
            if !self.split.train.iter().any(|&v| self.availability[[v, c]]) {
                return Err(Error::invalid(
                    "availability",
                    format!(
                        "channel {c} (`{}`) is not available at any training view",
                        ch.label
                    ),
                ));
            }
        }
        Ok(())
    }

    fn check_references(&self) -> Result<()> {
        let Some(r) = &self.references else {
            return Ok(());
        };
        check_shape("references", r.shape(), &self.expected_reference_shape())?;
        check_finite("references", r.view().into_dyn(), |i| {
            format!("channel `{}`", self.channels[i[0]].label)
        })
    }

    fn check_materials(&self) -> Result<()> {
        let Some(m) = &self.materials else {
            return Ok(());
        };
        let [_, z, y, x] = self.expected_reference_shape();
        check_shape(
            "fractions",
            m.fractions.shape(),
            &[m.materials.len(), z, y, x],
        )?;
        check_finite("fractions", m.fractions.view().into_dyn(), |i| {
            format!("material `{}`", m.materials[i[0]].name())
        })
    }

    fn check_structural(&self) -> Result<()> {
        let Some(s) = &self.structural else {
            return Ok(());
        };
        let [_, v, r, u] = self.expected_projection_shape();
        check_shape("structural", s.shape(), &[v, r, u])?;
        check_finite("structural", s.view().into_dyn(), |_| {
            "full-spectrum projection".into()
        })
    }
}

/// Geometry, channels (order, τ) and split of a scene; nothing that needs the arrays.
fn check_metadata(geometry: &Geometry, channels: &[Channel], split: &Split) -> Result<()> {
    geometry.validate().map_err(|e| e.under("geometry"))?;
    let (lo, hi) = check_channel_order(channels)?;
    for (i, ch) in channels.iter().enumerate() {
        let want = tau_of(ch.coordinate.value(), lo, hi);
        if !(ch.tau.is_finite() && (ch.tau - want).abs() <= 1e-9) {
            return Err(Error::invalid(
                format!("channels[{i}].tau"),
                format!(
                    "is {} but the normalised coordinate is {want} (call normalise_tau)",
                    ch.tau
                ),
            ));
        }
    }
    let views = geometry.views();
    for (name, list) in [("train", &split.train), ("test", &split.test)] {
        for (k, &v) in list.iter().enumerate() {
            let field = format!("split.{name}[{k}]");
            if v >= views {
                return Err(Error::invalid(
                    field,
                    format!("view {v} is out of range (the scene has {views} views)"),
                ));
            }
            if list[..k].contains(&v) {
                return Err(Error::invalid(field, format!("view {v} is listed twice")));
            }
        }
    }
    if let Some((k, v)) = split
        .test
        .iter()
        .enumerate()
        .find(|(_, v)| split.train.contains(v))
    {
        return Err(Error::invalid(
            format!("split.test[{k}]"),
            format!("view {v} is also a training view; train and test must be disjoint"),
        ));
    }
    Ok(())
}

/// Shape check; the message gives expected and found shapes.
pub(crate) fn check_shape(field: &str, found: &[usize], expected: &[usize]) -> Result<()> {
    if found == expected {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            format!("wrong shape: expected {expected:?}, found {found:?}"),
        ))
    }
}

/// Finiteness check; the error names the first bad index (C order) as `field[i][j]…` and
/// `what(index)` describes it (e.g. the channel).
pub(crate) fn check_finite(
    field: &str,
    a: ndarray::ArrayViewD<'_, f32>,
    what: impl Fn(&[usize]) -> String,
) -> Result<()> {
    let Some(flat) = a.iter().position(|x| !x.is_finite()) else {
        return Ok(());
    };
    let x = a.iter().nth(flat).copied().unwrap_or(f32::NAN);
    // Unravel the logical (C-order) position into an index.
    let mut idx = vec![0; a.ndim()];
    let mut rest = flat;
    for (k, &n) in a.shape().iter().enumerate().rev() {
        idx[k] = rest % n;
        rest /= n;
    }
    let path: String = idx.iter().map(|i| format!("[{i}]")).collect();
    Err(Error::invalid(
        format!("{field}{path}"),
        format!("value {x} is not finite ({}; first bad value)", what(&idx)),
    ))
}

#[cfg(test)]
mod tests;
