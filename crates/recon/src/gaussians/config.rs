//! The geometry stage's configuration ([`GeometryConfig`]): R²-Gaussian's whole configuration
//! and the part of 4D-SG's that fits its shared geometry. Every section has one [`Default`]
//! that states its defaults once; partial sections take the rest from it.

use super::adam::LogLinear;
use super::host::ScaleBounds;
use crate::device::DeviceChoice;
use crate::{Error, Result};
use prism_render::{ProjectOptions, ProjectionMode};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The geometry stage's configuration: a set of 3D Gaussians initialised from FDK and fitted to
/// projections. Lengths are in the normalised world (the volume's largest edge spans 2),
/// densities in units of the FDK's 99.9th percentile. Every field has a default
/// ([`GeometryConfig::default`]). Its fields are top-level keys of a method's YAML, beside the
/// method's own; the method's loader refuses keys that no part of its config reads
/// ([`flat`]), so this struct ignores unknown keys itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct GeometryConfig {
    pub seed: u64,
    /// Iterations of the geometry stage (per channel for `r2gs`; upstream 30 000; default 1500,
    /// a CPU budget).
    pub iterations: usize,
    pub init: InitConfig,
    /// Scale activation bounds as fractions of the normalised volume extent (upstream and default
    /// 0.0005, 0.5, i.e. 0.001 and 1.0 in normalised units).
    pub scale_bounds: ScaleBounds,
    pub lr: LearningRates,
    pub loss: LossConfig,
    /// How many training views one step fits: `cover` (default) or `one` ([`ViewsPerStep`]).
    pub views_per_step: ViewsPerStep,
    /// How training views are rendered (`mode: affine | exact`, `cutoff`); the trained model
    /// keeps it, so queries render the same way.
    pub projection: ProjectionConfig,
    /// Adaptive density control; `null` turns it off.
    pub densify: Option<DensifyConfig>,
    /// Evaluate (voxelize, PSNR/SSIM) every this many iterations; 0: only at the end of a stage
    /// (default 250).
    pub eval_every: usize,
    /// Save the run's state every this many iterations of a stage, to continue it with
    /// `prism recon --resume` (`crate::gaussians::train::checkpoints`); 0 (default): only when the run is
    /// interrupted or diverges.
    pub checkpoint_every: usize,
    /// Where training runs: `cpu` (Flex) or `wgpu` (the GPU, or lavapipe without one; needs a
    /// `prism` built with `--features wgpu`). `prism recon --device` overrides it.
    pub device: DeviceChoice,
}

impl Default for GeometryConfig {
    fn default() -> Self {
        GeometryConfig {
            seed: 0,
            iterations: 1500,
            init: InitConfig::default(),
            scale_bounds: ScaleBounds {
                min: 0.0005,
                max: 0.5,
            },
            lr: LearningRates::default(),
            loss: LossConfig::default(),
            views_per_step: ViewsPerStep::default(),
            projection: ProjectionConfig::default(),
            densify: Some(DensifyConfig::default()),
            eval_every: 250,
            checkpoint_every: 0,
            device: DeviceChoice::default(),
        }
    }
}

/// How many training views one step fits (YAML `views_per_step`). Either way a step draws its
/// views from the current pass over the training views (each view once per pass, reshuffled),
/// and its loss is the mean over the images it fits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewsPerStep {
    /// After the first view, the next view of the pass that measures a channel not yet fitted,
    /// until every channel is or the pass has none left: one view where each view measures every
    /// channel (a shared acquisition, or one channel), one of each channel on an interleaved scan.
    /// Every step then fits every channel, so the iteration count means the same on both kinds
    /// of scan.
    #[default]
    Cover,
    /// One view per step, whatever it measures (R²-Gaussian upstream): on an interleaved scan
    /// each channel is fitted at 1/C of the steps.
    One,
}

/// Projection settings of training and of queries (YAML `projection:`; every field optional).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProjectionConfig {
    /// `affine` (R²-Gaussian's splat; a first-order approximation in cone beam) or `exact` (the
    /// closed-form integral along every pixel's ray; on the CPU about 27× the render cost).
    pub mode: ProjectionMode,
    /// A pixel receives a Gaussian only if its ray passes within `cutoff` standard deviations of
    /// the centre (upstream 3: the dropped tail is e^{−cutoff²/2} = 1.1 % of the peak).
    pub cutoff: f64,
}

impl Default for ProjectionConfig {
    fn default() -> Self {
        let o = ProjectOptions::default();
        ProjectionConfig {
            mode: o.mode,
            cutoff: o.cutoff,
        }
    }
}

impl ProjectionConfig {
    /// The render op's options.
    pub fn options(&self) -> ProjectOptions {
        ProjectOptions {
            mode: self.mode,
            cutoff: self.cutoff,
            ..ProjectOptions::default()
        }
    }

    pub fn validate(&self) -> Result<()> {
        self.options()
            .validate()
            .map_err(|e| Error::invalid(format!("projection.{}", e.field), e.message))
    }
}

impl GeometryConfig {
    /// Scale bounds in normalised length units (the extent is 2).
    pub fn bounds(&self) -> ScaleBounds {
        ScaleBounds {
            min: 2.0 * self.scale_bounds.min,
            max: 2.0 * self.scale_bounds.max,
        }
    }

    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::invalid("iterations", "must be at least 1"));
        }
        self.init.validate()?;
        self.scale_bounds.validate()?;
        self.lr.validate()?;
        self.loss.validate()?;
        self.projection.validate()?;
        if let Some(d) = &self.densify {
            d.validate()?;
        }
        Ok(())
    }
}

/// How the initial densities are scaled from the FDK values.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DensityRescale {
    /// A fixed factor (upstream: 0.15, "to account for occlusion").
    Factor(f64),
    /// `fit`: least squares against the FDK volume.
    Named(RescaleRule),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RescaleRule {
    Fit,
}

/// Initialisation settings (YAML `init:`; every field optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitConfig {
    /// Number of Gaussians drawn from the candidate voxels (default 20 000, sized for the CPU
    /// scenes' 64³; upstream 50 000 at 256³).
    pub n_points: usize,
    /// Candidate threshold on the normalised FDK value (upstream 0.05).
    pub threshold: f64,
    /// Density scale factor: a number or `fit`.
    pub density_rescale: DensityRescale,
    /// Neighbours for the initial scale (upstream 3).
    pub neighbours: usize,
}

impl Default for InitConfig {
    fn default() -> Self {
        InitConfig {
            n_points: 20_000,
            threshold: 0.05,
            density_rescale: DensityRescale::Factor(0.15),
            neighbours: 3,
        }
    }
}

impl InitConfig {
    pub fn validate(&self) -> Result<()> {
        if self.n_points == 0 {
            return Err(Error::invalid("init.n_points", "must be at least 1"));
        }
        if self.neighbours == 0 {
            return Err(Error::invalid("init.neighbours", "must be at least 1"));
        }
        prism_domain::error::ensure_finite("init.threshold", self.threshold)?;
        if let DensityRescale::Factor(f) = self.density_rescale {
            prism_domain::error::ensure_positive("init.density_rescale", f)?;
        }
        Ok(())
    }
}

/// Learning rates per parameter group (YAML `lr:`), log-linear from `init` to `final` over a
/// stage; the defaults are upstream R²-Gaussian's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearningRates {
    pub position: LogLinear,
    pub density: LogLinear,
    pub scale: LogLinear,
    pub rotation: LogLinear,
}

impl Default for LearningRates {
    fn default() -> Self {
        let ll = |init, end| LogLinear { init, end };
        LearningRates {
            position: ll(2e-4, 2e-5),
            density: ll(1e-2, 1e-3),
            scale: ll(5e-3, 5e-4),
            rotation: ll(1e-3, 1e-4),
        }
    }
}

impl LearningRates {
    pub fn validate(&self) -> Result<()> {
        self.position.validate("lr.position")?;
        self.density.validate("lr.density")?;
        self.scale.validate("lr.scale")?;
        self.rotation.validate("lr.rotation")
    }

    /// The rates of step `t` (0-based) of `steps`.
    pub fn at(&self, t: usize, steps: usize) -> Rates {
        Rates {
            position: self.position.at(t, steps),
            density: self.density.at(t, steps),
            scale: self.scale.at(t, steps),
            rotation: self.rotation.at(t, steps),
        }
    }
}

/// The learning rates of one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rates {
    pub position: f64,
    pub density: f64,
    pub scale: f64,
    pub rotation: f64,
}

/// Loss weights (YAML `loss:`; upstream's by default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LossConfig {
    /// Weight of `1 − SSIM` on projections (upstream 0.25; 0 skips SSIM).
    pub lambda_dssim: f64,
    /// Weight of the TV of a random voxelized patch (upstream 0.05; 0 skips the voxelization).
    pub lambda_tv: f64,
    /// Edge of the TV patch in voxels of the reconstruction grid (upstream 32).
    pub tv_patch: usize,
    /// How the L1 term weighs each pixel: `none` (upstream, default) or `counts` for
    /// photon-limited data ([`DataWeighting`]). Left out of a resolved config when `none`, so
    /// configs written before the option existed still describe their runs.
    #[serde(skip_serializing_if = "DataWeighting::is_none")]
    pub weighting: DataWeighting,
    /// The data term's norm over a projection's residuals: `l1` (upstream, default) or `rms`
    /// ([`DataNorm`]). Left out of a resolved config when `l1`.
    #[serde(skip_serializing_if = "DataNorm::is_l1")]
    pub data: DataNorm,
    /// With several channels in one model (4D-SG's stage 2), each channel's TV guided by the
    /// channels' mean (YAML `loss.tv_guide: {eta: …}`): directional TV
    /// ([`directional_total_variation`]), which spares a channel's gradient along the mean's
    /// edges, in place of each channel's own TV. Absent (default): each channel's own TV, as a
    /// model of one channel (or of basis materials: stage 1's joint fit; the basis head
    /// refuses it) always takes. Left out of a resolved config when absent.
    ///
    /// [`directional_total_variation`]: crate::gaussians::train::loss::directional_total_variation
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tv_guide: Option<TvGuide>,
    /// Each channel's TV weight as a multiple of `lambda_tv`, by channel label (YAML
    /// `loss.tv_channel_weight: {120kVp: 3}`; a channel not named weighs 1). It applies where a
    /// model's densities are the scene's channels: each of R²-Gaussian's channel models and the
    /// channels of 4D-SG's stage 2; stage 1's common density keeps `lambda_tv`, and the basis
    /// head (whose TV is over materials) refuses it. Left out of a resolved config when empty.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub tv_channel_weight: BTreeMap<String, f64>,
}

/// Directional TV's guide (YAML `loss.tv_guide`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TvGuide {
    /// Edge parameter η as a fraction of the guide's largest gradient in the TV patch: where the
    /// mean's gradient is well above η, a channel's gradient along it is spared; well below, TV
    /// is isotropic.
    pub eta: f64,
}

/// How the data term weighs a pixel's residual (YAML `loss.weighting`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DataWeighting {
    /// Every pixel alike (R²-Gaussian's L1).
    #[default]
    None,
    /// Photon statistics: a log-transformed count `b = −ln(I/I₀)` has standard deviation
    /// `≈ e^{b/2}/√I₀` (Poisson), so each pixel's absolute residual is weighted by `1/σ ∝
    /// e^{−b/2}` (the L1 term then is a Laplace likelihood with the noise's own scale),
    /// normalised to mean 1 over each channel's pixels at the stage's views; no I₀ needed.
    /// SSIM and TV are left as they are.
    Counts,
}

/// The data term's norm over one projection image's residuals (YAML `loss.data`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DataNorm {
    /// The mean absolute residual (R²-Gaussian's): a Laplace likelihood.
    #[default]
    L1,
    /// The root-mean-square residual of each channel's image, averaged over the images: the
    /// least-squares fit a Gaussian noise model asks for, each image weighted against the
    /// priors by its own residual level (a noisier channel is regularised more). With
    /// `weighting: counts` each residual is scaled by its weight first (weighted least squares).
    Rms,
}

impl DataNorm {
    fn is_l1(&self) -> bool {
        *self == DataNorm::L1
    }
}

impl DataWeighting {
    fn is_none(&self) -> bool {
        *self == DataWeighting::None
    }
}

impl Default for LossConfig {
    fn default() -> Self {
        LossConfig {
            lambda_dssim: 0.25,
            lambda_tv: 0.05,
            tv_patch: 32,
            weighting: DataWeighting::None,
            data: DataNorm::L1,
            tv_guide: None,
            tv_channel_weight: BTreeMap::new(),
        }
    }
}

impl LossConfig {
    pub fn validate(&self) -> Result<()> {
        for (f, v) in [
            ("loss.lambda_dssim", self.lambda_dssim),
            ("loss.lambda_tv", self.lambda_tv),
        ] {
            prism_domain::error::ensure_non_negative(f, v)?;
        }
        if let Some(g) = &self.tv_guide {
            prism_domain::error::ensure_positive("loss.tv_guide.eta", g.eta)?;
        }
        for (label, &w) in &self.tv_channel_weight {
            prism_domain::error::ensure_non_negative(format!("loss.tv_channel_weight.{label}"), w)?;
        }
        if self.lambda_tv > 0.0 && self.tv_patch < 2 {
            return Err(Error::invalid("loss.tv_patch", "must be at least 2 voxels"));
        }
        Ok(())
    }

    /// The TV weight of each of `channels` (labels, in a model's channel order) as a multiple of
    /// `lambda_tv`; an error names a key of `tv_channel_weight` that is none of them.
    pub fn channel_tv_weights(&self, channels: &[&str]) -> Result<Vec<f64>> {
        if let Some(label) = self
            .tv_channel_weight
            .keys()
            .find(|l| !channels.contains(&l.as_str()))
        {
            return Err(Error::invalid(
                format!("loss.tv_channel_weight.{label}"),
                format!("no channel `{label}` (channels: {channels:?})"),
            ));
        }
        Ok(channels
            .iter()
            .map(|c| self.tv_channel_weight.get(*c).copied().unwrap_or(1.0))
            .collect())
    }
}

/// Densification settings (YAML `densify:`; every field optional), normalised-world units. The
/// window defaults to the CPU budget's (100 to 750 of 1500 iterations); upstream densifies from
/// 500 to 15 000 of 30 000 (`configs/recon/r2gs-upstream.yaml`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DensifyConfig {
    /// Densify at iterations `from < it < until` with `it % every == 0` (default 100, 750, 100;
    /// upstream 500, 15000, 100).
    pub from: usize,
    pub until: usize,
    pub every: usize,
    /// Threshold on the mean view-space gradient norm in NDC units (upstream 5e-5). Our render op
    /// reports it per pixel; it is converted with half the detector size in pixels.
    pub grad_threshold: f64,
    /// Largest scale (fraction of the normalised volume extent, 2) that is cloned; larger ones
    /// are split (upstream 0.1).
    pub clone_max_scale: f64,
    /// No densification once the model holds this many Gaussians (upstream 500 000).
    pub max_gaussians: usize,
    /// Prune Gaussians whose densities all fall below this (normalised units, upstream 1e-5).
    pub min_density: f64,
}

impl Default for DensifyConfig {
    fn default() -> Self {
        DensifyConfig {
            from: 100,
            until: 750,
            every: 100,
            grad_threshold: 5e-5,
            clone_max_scale: 0.1,
            max_gaussians: 500_000,
            min_density: 1e-5,
        }
    }
}

impl DensifyConfig {
    pub fn validate(&self) -> Result<()> {
        if self.every == 0 {
            return Err(Error::invalid("densify.every", "must be at least 1"));
        }
        prism_domain::error::ensure_positive("densify.grad_threshold", self.grad_threshold)?;
        prism_domain::error::ensure_positive("densify.clone_max_scale", self.clone_max_scale)?;
        prism_domain::error::ensure_finite("densify.min_density", self.min_density)?;
        Ok(())
    }

    /// Whether iteration `it` (1-based) densifies.
    pub fn due(&self, it: usize) -> bool {
        it > self.from && it < self.until && it.is_multiple_of(self.every)
    }
}

/// A method's YAML is one flat mapping: `method`, the geometry stage's keys and the method's own
/// beside them. These read and write such a mapping part by part: each part is parsed from the
/// text itself (serde_yaml_ng names field paths only when it reads text), and a top-level key
/// that no part reads is refused, naming the file.
pub mod flat {
    use crate::{Error, Result};
    use serde::Serialize;
    use serde::de::DeserializeOwned;
    use serde_yaml_ng::{Mapping, Value};
    use std::path::Path;

    /// The top-level keys a part reads: the fields of its default.
    pub fn keys<T: Serialize + Default>() -> Vec<String> {
        match serde_yaml_ng::to_value(T::default()) {
            Ok(Value::Mapping(m)) => m
                .keys()
                .filter_map(|k| k.as_str().map(String::from))
                .collect(),
            _ => Vec::new(),
        }
    }

    /// One part of the flat mapping in `text` (keys of other parts are left to them).
    pub fn read<T: DeserializeOwned>(text: &str, file: &Path) -> Result<T> {
        serde_yaml_ng::from_str(text).map_err(|e| prism_domain::yaml::error(file, &e).into())
    }

    /// An error for the first top-level key of `text` outside `known` (and `method`).
    pub fn refuse_unknown(text: &str, file: &Path, method: &str, known: &[String]) -> Result<()> {
        let value: Value = serde_yaml_ng::from_str(text)
            .map_err(|e| Error::from(prism_domain::yaml::error(file, &e)))?;
        let Value::Mapping(m) = value else {
            return Err(Error::field(file, ".", "expected a mapping of settings"));
        };
        for key in m.keys() {
            let name = key.as_str().unwrap_or_default();
            if name != "method" && !known.iter().any(|k| k == name) {
                return Err(Error::field(
                    file,
                    if name.is_empty() { "." } else { name },
                    format!(
                        "`{method}` has no setting `{}` (its settings: method, {})",
                        serde_yaml_ng::to_string(key).unwrap_or_default().trim(),
                        known.join(", ")
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The parts (each `serde_yaml_ng::to_value` of a part) joined into one mapping, `method`
    /// first, and serialised with `s`.
    pub fn join<S: serde::Serializer>(
        method: &str,
        parts: Vec<serde_yaml_ng::Result<Value>>,
        s: S,
    ) -> std::result::Result<S::Ok, S::Error> {
        let mut out = Mapping::new();
        out.insert("method".into(), method.into());
        for part in parts {
            match part.map_err(serde::ser::Error::custom)? {
                Value::Mapping(m) => out.extend(m),
                _ => return Err(serde::ser::Error::custom("a config part is not a mapping")),
            }
        }
        out.serialize(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_tv_weights_follow_the_labels_and_name_an_unknown_one() {
        let mut loss = LossConfig::default();
        assert_eq!(
            loss.channel_tv_weights(&["50kVp", "80kVp"]).unwrap(),
            [1.0, 1.0]
        );
        loss.tv_channel_weight.insert("80kVp".into(), 3.0);
        assert_eq!(
            loss.channel_tv_weights(&["50kVp", "80kVp"]).unwrap(),
            [1.0, 3.0]
        );
        let e = loss.channel_tv_weights(&["50kVp"]).unwrap_err().to_string();
        assert!(
            e.contains("loss.tv_channel_weight.80kVp") && e.contains("50kVp"),
            "{e}"
        );
        loss.tv_channel_weight.insert("120kVp".into(), -1.0);
        let e = loss.validate().unwrap_err().to_string();
        assert!(e.contains("loss.tv_channel_weight.120kVp"), "{e}");
        // Empty, it stays out of a resolved config (old configs still describe their runs).
        let yaml = serde_yaml_ng::to_string(&LossConfig::default()).unwrap();
        assert!(!yaml.contains("tv_channel_weight"), "{yaml}");
    }
}
