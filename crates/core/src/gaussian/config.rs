//! Configuration of the Gaussian methods (YAML), every hyperparameter with its default.

use super::adam::LogLinear;
use super::densify::DensifyConfig;
use super::host::ScaleBounds;
use super::init::InitConfig;
use super::model::Learnable;
use super::trainer::{LearningRates, LossConfig};
use crate::scene::Scene;
use crate::{Error, Result};
use prism_gscnet::CurveModelConfig;
use prism_render::{ProjectOptions, ProjectionMode};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The Gaussian reconstruction methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GaussianMethod {
    /// R²-Gaussian, every channel reconstructed independently.
    #[serde(rename = "r2gs")]
    R2gs,
    /// 4D-SG stage 1: shared geometry from the structural projections, then per-channel densities
    /// fitted directly on the fixed geometry (no curve model).
    #[serde(rename = "4dsg-stage1")]
    Stage1,
    /// 4D-SG: stage 1 (shared geometry), then stage 2 (the curve model predicts every
    /// Gaussian's raw density curve over the spectral grid).
    #[serde(rename = "4dsg")]
    FourDsg,
}

impl GaussianMethod {
    pub fn name(self) -> &'static str {
        match self {
            GaussianMethod::R2gs => "r2gs",
            GaussianMethod::Stage1 => "4dsg-stage1",
            GaussianMethod::FourDsg => "4dsg",
        }
    }
}

/// Where stage 1's structural projection comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StructuralSource {
    /// The scene's measured full-spectrum projection when it has one, else `mean`.
    #[default]
    Auto,
    /// Mean over the channels at each view (conventional spectral CT); views where a channel is
    /// missing are left out of the structural stage.
    Mean,
    /// The scene's measured full-spectrum projection (photon-counting); an error if absent.
    Provided,
}

/// A Gaussian method's configuration. Lengths are in the normalised world (the volume's largest
/// edge spans 2), densities in units of the FDK's 99.9th percentile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GaussianConfig {
    pub method: GaussianMethod,
    #[serde(default)]
    pub seed: u64,
    /// Iterations of the geometry stage (per channel for `r2gs`; upstream 30 000).
    #[serde(default = "default_iterations")]
    pub iterations: usize,
    /// `4dsg-stage1`: iterations of the per-channel density fit on the fixed geometry.
    #[serde(default = "default_density_iterations")]
    pub density_iterations: usize,
    #[serde(default = "default_init")]
    pub init: InitConfig,
    /// Scale activation bounds as fractions of the normalised volume extent (upstream 0.0005,
    /// 0.5, i.e. 0.001 and 1.0 in normalised units).
    #[serde(default = "default_bounds")]
    pub scale_bounds: ScaleBounds,
    #[serde(default)]
    pub lr: LearningRates,
    #[serde(default)]
    pub loss: LossConfig,
    /// How training views are rendered (`mode: affine | exact`, `cutoff`); the trained model
    /// keeps it, so queries render the same way.
    #[serde(default)]
    pub projection: ProjectionConfig,
    /// Adaptive density control; `null` turns it off.
    #[serde(default = "default_densify")]
    pub densify: Option<DensifyConfig>,
    /// Evaluate (voxelize, PSNR/SSIM) every this many iterations; 0: only at the end of a stage.
    #[serde(default = "default_eval_every")]
    pub eval_every: usize,
    #[serde(default)]
    pub structural: StructuralSource,
    /// `4dsg`: stage 2 (curve model) settings.
    #[serde(default)]
    pub stage2: Stage2Config,
    /// Channel labels left out of training entirely; spectral methods predict them from the
    /// curve of the observed channels and score the prediction (`holdout.json`).
    #[serde(default)]
    pub holdout_channels: Vec<String>,
    /// Where training runs: `cpu` (Flex) or `wgpu` (the GPU, or lavapipe without one; needs a
    /// `prism` built with `--features wgpu`). `prism recon --device` overrides it.
    #[serde(default)]
    pub device: DeviceChoice,
}

/// Projection settings of training and of queries (YAML `projection:`; every field optional).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProjectionConfig {
    /// `affine` (R²-Gaussian's splat; a first-order approximation in cone beam) or `exact` (the
    /// closed-form integral along every pixel's ray; on the CPU about 16× the cost).
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

/// The compute device of a Gaussian run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceChoice {
    /// Burn's Flex backend with Prism's rayon kernels.
    #[default]
    Cpu,
    /// Burn's wgpu backend with Prism's CubeCL kernels.
    Wgpu,
}

impl DeviceChoice {
    /// The Burn device, or an error if this build lacks the backend.
    pub fn device(self) -> Result<burn::tensor::Device> {
        match self {
            DeviceChoice::Cpu => Ok(super::cpu_device()),
            #[cfg(feature = "wgpu")]
            DeviceChoice::Wgpu => Ok(burn::tensor::Device::wgpu(
                burn::tensor::DeviceKind::DefaultDevice,
            )),
            #[cfg(not(feature = "wgpu"))]
            DeviceChoice::Wgpu => Err(Error::Invalid {
                field: "device".into(),
                message: "wgpu needs a prism built with `--features wgpu`".into(),
            }),
        }
    }
}

/// Which parameter groups stay fixed in stage 2 (the paper's freezing strategies).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Freeze {
    pub position: bool,
    pub rotation: bool,
    pub scale: bool,
    /// The common raw density u⁽ᶜ⁾.
    pub density: bool,
}

impl Default for Freeze {
    /// Everything learnable (LLLL): measured best here (`prism ablate freeze`: +1.34 dB on
    /// phantom-3mono and +0.43 dB on chest-3mono over FFFL). The paper fixes the geometry
    /// ([`Freeze::PAPER`]).
    fn default() -> Self {
        Freeze {
            position: false,
            rotation: false,
            scale: false,
            density: false,
        }
    }
}

impl Freeze {
    /// The paper's strategy (FFFL): geometry fixed, common densities learnable.
    pub const PAPER: Freeze = Freeze {
        position: true,
        rotation: true,
        scale: true,
        density: false,
    };

    pub fn learnable(&self) -> Learnable {
        Learnable {
            position: !self.position,
            rotation: !self.rotation,
            scale: !self.scale,
            density: !self.density,
        }
    }
}

/// Stage 2 of `4dsg` (YAML `stage2:`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Stage2Config {
    /// Iterations (paper: 5000 after 30 000 of stage 1; default 1000: on chest-3mono, 500 → 1000
    /// gave +0.41 dB).
    pub iterations: usize,
    /// GSC-Net (`kind: gscnet`) or the direct MLP (`kind: mlp`) and their sizes.
    pub curve_model: CurveModelConfig,
    /// Weight of L_curve, the first-order smoothness of Δu along the spectral axis.
    pub lambda_curve: f64,
    /// Adam learning rate of the network (log-linear decay).
    pub lr_network: LogLinear,
    pub freeze: Freeze,
    /// Condition the network's density input on the stage-1 raw densities (centre: median,
    /// scale: half the 10–90 % range) instead of the fixed û = u/(s + |u|) (default true: the
    /// fixed form left the occupied raw densities in a fifth of û's range; measured on
    /// phantom-3mono 40.37 dB against 36.22 dB).
    pub condition_on_stage1: bool,
}

impl Default for Stage2Config {
    fn default() -> Self {
        Stage2Config {
            iterations: 1000,
            curve_model: CurveModelConfig::default(),
            lambda_curve: 0.01,
            lr_network: LogLinear {
                init: 1e-3,
                end: 1e-4,
            },
            freeze: Freeze::default(),
            condition_on_stage1: true,
        }
    }
}

fn default_iterations() -> usize {
    1500
}
fn default_density_iterations() -> usize {
    500
}
fn default_init() -> InitConfig {
    InitConfig {
        n_points: 20_000,
        ..InitConfig::default()
    }
}
fn default_bounds() -> ScaleBounds {
    ScaleBounds {
        min: 0.0005,
        max: 0.5,
    }
}
fn default_densify() -> Option<DensifyConfig> {
    Some(DensifyConfig {
        from: 100,
        until: 750,
        ..DensifyConfig::default()
    })
}
fn default_eval_every() -> usize {
    250
}

impl GaussianConfig {
    /// A configuration for `method` with every default.
    pub fn new(method: GaussianMethod) -> Self {
        GaussianConfig {
            method,
            seed: 0,
            iterations: default_iterations(),
            density_iterations: default_density_iterations(),
            init: default_init(),
            scale_bounds: default_bounds(),
            lr: LearningRates::default(),
            loss: LossConfig::default(),
            projection: ProjectionConfig::default(),
            densify: default_densify(),
            eval_every: default_eval_every(),
            structural: StructuralSource::Auto,
            stage2: Stage2Config::default(),
            holdout_channels: Vec::new(),
            device: DeviceChoice::default(),
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
                        "`{label}` is at the end of the spectral grid: predicting it would need                          extrapolation; hold out an intermediate channel"
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
            serde_yaml_ng::from_str(text).map_err(|e| crate::yaml::error(file, &e))?;
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
            let s2 = &self.stage2;
            if s2.iterations == 0 {
                return Err(Error::invalid("stage2.iterations", "must be at least 1"));
            }
            s2.curve_model
                .validate()
                .map_err(|e| Error::invalid("stage2.curve_model", e.to_string()))?;
            if !(s2.lambda_curve.is_finite() && s2.lambda_curve >= 0.0) {
                return Err(Error::invalid(
                    "stage2.lambda_curve",
                    format!("must be finite and ≥ 0, got {}", s2.lambda_curve),
                ));
            }
            s2.lr_network.validate("stage2.lr_network")?;
        }
        Ok(())
    }
}
