//! Configuration of the Gaussian methods (YAML `method: r2gs | 4dsg-stage1 | 4dsg`): every
//! section of the YAML, each with one [`Default`] that states its defaults once; partial
//! sections take the rest from it. The stages read their sections from here.

use super::adam::LogLinear;
use super::host::ScaleBounds;
use crate::device::DeviceChoice;
use crate::{Error, Result};
use prism_domain::scene::Scene;
use prism_render::{ProjectOptions, ProjectionMode};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub use super::spectral::config::{BasisConfig, Freeze, Stage2Config};

/// The Gaussian reconstruction methods (their names: [`crate::Method`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "crate::Method", into = "crate::Method")]
pub enum GaussianMethod {
    /// R²-Gaussian, every channel reconstructed independently.
    R2gs,
    /// 4D-SG stage 1: shared geometry from the structural projections, then per-channel densities
    /// fitted directly on the fixed geometry (no curve model).
    Stage1,
    /// 4D-SG: stage 1 (shared geometry), then stage 2 (the curve model predicts every
    /// Gaussian's raw density curve over the spectral grid).
    FourDsg,
}

impl GaussianMethod {
    pub fn name(self) -> &'static str {
        crate::Method::from(self).name()
    }
}

/// A Gaussian method's configuration. Lengths are in the normalised world (the volume's largest
/// edge spans 2), densities in units of the FDK's 99.9th percentile. Every field has a default
/// ([`GaussianConfig::default`]; `method` is read first, by [`crate::MethodConfig`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GaussianConfig {
    pub method: GaussianMethod,
    pub seed: u64,
    /// Iterations of the geometry stage (per channel for `r2gs`; upstream 30 000; default 1500,
    /// a CPU budget).
    pub iterations: usize,
    /// `4dsg-stage1`: iterations of the per-channel density fit on the fixed geometry (default 500).
    pub density_iterations: usize,
    pub init: InitConfig,
    /// Scale activation bounds as fractions of the normalised volume extent (upstream and default
    /// 0.0005, 0.5, i.e. 0.001 and 1.0 in normalised units).
    pub scale_bounds: ScaleBounds,
    pub lr: LearningRates,
    pub loss: LossConfig,
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
    pub structural: StructuralSource,
    /// `structural: joint`: the basis stage 1 fits every channel in.
    pub joint: JointConfig,
    /// `4dsg`: stage 2 (curve model) settings.
    pub stage2: Stage2Config,
    /// Channel labels left out of training entirely; spectral methods predict them from the
    /// curve of the observed channels and score the prediction (`holdout.json`).
    pub holdout_channels: Vec<String>,
    /// Where training runs: `cpu` (Flex) or `wgpu` (the GPU, or lavapipe without one; needs a
    /// `prism` built with `--features wgpu`). `prism recon --device` overrides it.
    pub device: DeviceChoice,
}

impl Default for GaussianConfig {
    fn default() -> Self {
        GaussianConfig {
            method: GaussianMethod::R2gs,
            seed: 0,
            iterations: 1500,
            density_iterations: 500,
            init: InitConfig::default(),
            scale_bounds: ScaleBounds {
                min: 0.0005,
                max: 0.5,
            },
            lr: LearningRates::default(),
            loss: LossConfig::default(),
            projection: ProjectionConfig::default(),
            densify: Some(DensifyConfig::default()),
            eval_every: 250,
            checkpoint_every: 0,
            structural: StructuralSource::default(),
            joint: JointConfig::default(),
            stage2: Stage2Config::default(),
            holdout_channels: Vec::new(),
            device: DeviceChoice::default(),
        }
    }
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

impl GaussianConfig {
    /// A configuration for `method` with every default.
    pub fn new(method: GaussianMethod) -> Self {
        GaussianConfig {
            method,
            ..GaussianConfig::default()
        }
    }

    /// Indices of the held-out channels in `scene`; errors name unknown labels, held-out
    /// channels at the ends of the spectral grid (they would need extrapolation), or a method
    /// that cannot predict unobserved channels.
    pub fn holdout_indices(&self, scene: &Scene) -> Result<Vec<usize>> {
        if self.holdout_channels.is_empty() {
            return Ok(Vec::new());
        }
        if self.method == GaussianMethod::R2gs {
            return Err(Error::invalid(
                "holdout_channels",
                "r2gs reconstructs channels independently and cannot predict an unobserved one",
            ));
        }
        let m = scene.n_channels();
        let mut out = Vec::new();
        for (i, label) in self.holdout_channels.iter().enumerate() {
            let field = format!("holdout_channels[{i}]");
            let c = scene
                .channels
                .iter()
                .position(|ch| &ch.label == label)
                .ok_or_else(|| {
                    let known: Vec<&str> =
                        scene.channels.iter().map(|c| c.label.as_str()).collect();
                    Error::invalid(
                        &field,
                        format!("no channel `{label}` (channels: {known:?})"),
                    )
                })?;
            if c == 0 || c + 1 == m {
                return Err(Error::invalid(
                    &field,
                    format!(
                        "`{label}` is at the end of the spectral grid: predicting it would need \
                         extrapolation; hold out an intermediate channel"
                    ),
                ));
            }
            out.push(c);
        }
        out.sort_unstable();
        out.dedup();
        if m - out.len() < 2 {
            return Err(Error::invalid(
                "holdout_channels",
                "at least two observed channels must remain",
            ));
        }
        Ok(out)
    }

    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let cfg: GaussianConfig =
            serde_yaml_ng::from_str(text).map_err(|e| prism_domain::yaml::error(file, &e))?;
        cfg.validate().map_err(|e| e.in_file(file))?;
        Ok(cfg)
    }

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
        if self.method == GaussianMethod::Stage1 && self.density_iterations == 0 {
            return Err(Error::invalid("density_iterations", "must be at least 1"));
        }
        self.init.validate()?;
        self.scale_bounds.validate()?;
        self.lr.validate()?;
        self.loss.validate()?;
        self.projection.validate()?;
        if let Some(d) = &self.densify {
            d.validate()?;
        }
        if self.method == GaussianMethod::FourDsg {
            self.stage2.validate()?;
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
}

impl Default for LossConfig {
    fn default() -> Self {
        LossConfig {
            lambda_dssim: 0.25,
            lambda_tv: 0.05,
            tv_patch: 32,
        }
    }
}

impl LossConfig {
    pub fn validate(&self) -> Result<()> {
        for (f, v) in [
            ("loss.lambda_dssim", self.lambda_dssim),
            ("loss.lambda_tv", self.lambda_tv),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(
                    f,
                    format!("must be finite and ≥ 0, got {v}"),
                ));
            }
        }
        if self.lambda_tv > 0.0 && self.tv_patch < 2 {
            return Err(Error::invalid("loss.tv_patch", "must be at least 2 voxels"));
        }
        Ok(())
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

/// Stage 1's joint fit (`structural: joint`; YAML `joint:`, every field optional): while the
/// shared geometry is fitted to every channel's projections, each Gaussian carries one density
/// per basis material and every channel is formed from them by the physics
/// ([`super::spectral::BasisHead`]). Two materials of different effective atomic number span,
/// between absorption edges, the photoelectric and Compton terms of every body material's
/// μ(E), so the channels constrain one another without a per-channel density; at the end of the
/// stage the densities become their channel mean, the common density stage 2 starts from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct JointConfig {
    /// Basis materials (default water and cortical bone).
    pub materials: Vec<prism_domain::physics::Material>,
    /// Share of the start density each material after the first takes (default 0.05).
    pub init_share: f64,
}

impl Default for JointConfig {
    fn default() -> Self {
        use prism_domain::physics::Material;
        JointConfig {
            materials: vec![Material::Water, Material::CorticalBone],
            init_share: 0.05,
        }
    }
}

impl JointConfig {
    /// The basis head's settings.
    pub fn basis(&self) -> BasisConfig {
        BasisConfig {
            materials: self.materials.clone(),
            init_share: self.init_share,
        }
    }
}

/// Where stage 1's structural projection comes from (YAML `structural:`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StructuralSource {
    /// The scene's measured full-spectrum projection when it has one; else `mean` when every
    /// training view has every channel; else `joint`.
    #[default]
    Auto,
    /// Mean over the channels at each view (conventional spectral CT); views where a channel is
    /// missing are left out of the structural stage.
    Mean,
    /// The scene's measured full-spectrum projection (photon-counting); an error if absent.
    Provided,
    /// Every measured projection of every channel at once, each channel formed from basis
    /// densities ([`JointConfig`]), so channels measured at different angles (interleaved, kV
    /// switching) all shape the geometry. Needs the channels' spectra (a simulated scene
    /// records them; otherwise tube-voltage channels assume the default filtration).
    Joint,
}
