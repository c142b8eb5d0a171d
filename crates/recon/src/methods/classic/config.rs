//! Configuration of the classic methods (YAML `method: fdk | sart | cgls | tv`): every field but
//! `method` has a default.

use crate::algorithms::{Coupling, Order, SartOptions, TvOptions, Weighting, Window};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Classic reconstruction method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "crate::Method", into = "crate::Method")]
pub enum ClassicMethod {
    /// FDK (cone) / FBP (parallel), one pass.
    Fdk,
    /// The SART family: SART (`block_size: 1`), OS-SART, SIRT (`block_size` ≥ views).
    Sart,
    /// CGLS on the exact Joseph pair.
    Cgls,
    /// TV-regularised least squares (PDHG), every channel at once with the channels coupled as
    /// `tv.coupling` says (total nuclear variation by default; `joint` is joint TV, `channel`
    /// per-channel TV).
    Tv,
}

impl ClassicMethod {
    /// Name as written in configs.
    pub fn name(self) -> &'static str {
        crate::Method::from(self).name()
    }
}

/// A classic reconstruction's configuration (YAML). Every field but `method` has a default
/// ([`ClassicConfig::default`] states them; `method` is read first, by
/// [`crate::MethodConfig`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClassicConfig {
    pub method: ClassicMethod,
    /// FDK ramp window: ram-lak (default), shepp-logan, cosine, hamming, hann.
    pub filter: Window,
    /// Epochs (SART family, default 3) or iterations (CGLS, default 10; TV, default
    /// [`TvConfig::ITERATIONS`]); ignored by FDK.
    /// Both methods semi-converge on sparse views (the data are not in the range of the discrete
    /// projector): on phantom-3mono at 50 views the mean PSNR was SART 39.5 / 35.3 / 33.7 dB at
    /// 3 / 10 / 20 epochs and CGLS 32.9 / 36.3 / 35.2 / 33.8 dB at 5 / 10 / 15 / 20 iterations.
    pub iterations: Option<usize>,
    /// SART family: views per block (1 = SART, default; ≥ views = SIRT).
    pub block_size: usize,
    /// SART family: relaxation λ > 0 (default 1).
    pub lambda: f64,
    /// SART family: λ multiplier after each epoch, in (0, 1] (default 1).
    pub lambda_decay: f64,
    /// SART family: block order, `random` (default, seeded) or `ordered`.
    pub order: Order,
    /// SART family: clip negative values (default true).
    pub nonneg: bool,
    /// Seed of the random block order (default 0).
    pub seed: u64,
    /// TV: the regulariser (`weight`, `coupling`); `nonneg` is its constraint x ≥ 0.
    pub tv: TvConfig,
    /// TV: where the iterate starts, `zero` (default) or `fdk` (each channel's FDK from its
    /// views, clipped at 0 under `nonneg`): nearer the minimum where the views are many. Only
    /// the primal starts there (the duals start at zero), so the gain is in the first iterations.
    #[serde(skip_serializing_if = "Start::is_zero")]
    pub start: Start,
}

/// Where an iterative method's volume starts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Start {
    #[default]
    Zero,
    Fdk,
}

impl Start {
    /// The default: left out of resolved configs, so runs made before the option still match.
    pub fn is_zero(&self) -> bool {
        *self == Start::Zero
    }
}

/// The regulariser of `method: tv` (YAML section `tv:`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TvConfig {
    /// λ ≥ 0 in mm (see `algorithms::tv`): the weight of the total variation of each channel
    /// divided by its gain (its mean measured line integral over the channels' mean). Default 1,
    /// the best of 0.1–3 for every coupling on chest-3mono interleaved (39 angles, 13 per
    /// channel, 64³; docs/methods.md).
    pub weight: f64,
    /// `channel` (per-channel TV), `joint` (joint TV) or `nuclear` (total nuclear variation,
    /// default: the best of the three on chest-3mono interleaved).
    pub coupling: Coupling,
    /// The data term's ray weights: `none` (least squares, default) or `counts` (statistical
    /// weights ∝ e^{−b}, for photon-limited data).
    pub weighting: Weighting,
    /// Directional TV (YAML `tv.guide: {eta, weight}`): every channel's gradient projected off
    /// the edges of a guide image, the TV reconstruction of the channels' mean sinogram (Cueva
    /// et al.'s side information from the summed sinograms; `algorithms::guide`). Absent
    /// (default): plain TV. Left out of a resolved config when absent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guide: Option<Guide>,
}

/// Directional TV's guide (YAML `tv.guide`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Guide {
    /// Edge parameter η as a fraction of the guide's largest gradient (Cueva et al.: 0.01).
    pub eta: f64,
    /// λ (mm) of the guide's own TV reconstruction from the channels' mean sinogram (channel
    /// TV, the run's iterations and start).
    pub weight: f64,
}

impl TvConfig {
    /// Default PDHG iterations.
    pub const ITERATIONS: usize = 300;
}

impl Default for TvConfig {
    fn default() -> Self {
        TvConfig {
            weight: 1.0,
            coupling: Coupling::default(),
            weighting: Weighting::default(),
            guide: None,
        }
    }
}

impl Default for ClassicConfig {
    fn default() -> Self {
        ClassicConfig {
            method: ClassicMethod::Fdk,
            filter: Window::default(),
            iterations: None,
            block_size: 1,
            lambda: 1.0,
            lambda_decay: 1.0,
            order: Order::default(),
            nonneg: true,
            seed: 0,
            tv: TvConfig::default(),
            start: Start::Zero,
        }
    }
}

impl ClassicConfig {
    /// A configuration for `method` with every default.
    pub fn new(method: ClassicMethod) -> Self {
        ClassicConfig {
            method,
            ..ClassicConfig::default()
        }
    }

    /// Parse and validate YAML; errors name the field and `file`.
    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let cfg: ClassicConfig =
            serde_yaml_ng::from_str(text).map_err(|e| prism_domain::yaml::error(file, &e))?;
        cfg.validate().map_err(|e| e.in_file(file))?;
        Ok(cfg)
    }

    /// The iteration count after defaults (0 for FDK).
    pub fn resolved_iterations(&self) -> usize {
        match (self.method, self.iterations) {
            (ClassicMethod::Fdk, _) => 0,
            (_, Some(n)) => n,
            (ClassicMethod::Sart, None) => 3,
            (ClassicMethod::Cgls, None) => 10,
            (ClassicMethod::Tv, None) => TvConfig::ITERATIONS,
        }
    }

    /// This configuration with defaults made explicit.
    pub fn resolved(&self) -> Self {
        let mut c = self.clone();
        c.iterations = Some(self.resolved_iterations());
        c
    }

    /// Check ranges; errors name the field.
    pub fn validate(&self) -> Result<()> {
        if self.method != ClassicMethod::Fdk && self.iterations == Some(0) {
            return Err(Error::invalid("iterations", "must be at least 1"));
        }
        if self.start == Start::Fdk && self.method != ClassicMethod::Tv {
            return Err(Error::invalid(
                "start",
                "`fdk` is a start of `method: tv` only",
            ));
        }
        if let Some(g) = &self.tv.guide {
            prism_domain::error::ensure_positive("tv.guide.eta", g.eta)?;
            prism_domain::error::ensure_non_negative("tv.guide.weight", g.weight)?;
            if self.method != ClassicMethod::Tv {
                return Err(Error::invalid("tv.guide", "a setting of `method: tv` only"));
            }
        }
        self.sart_options().validate()?;
        self.tv_options().validate()
    }

    pub(crate) fn tv_options(&self) -> TvOptions {
        TvOptions {
            iterations: self.resolved_iterations().max(1),
            weight: self.tv.weight,
            coupling: self.tv.coupling,
            weighting: self.tv.weighting,
            nonneg: self.nonneg,
        }
    }

    pub(crate) fn sart_options(&self) -> SartOptions {
        SartOptions {
            iterations: self.resolved_iterations().max(1),
            block_size: self.block_size,
            lambda: self.lambda,
            lambda_decay: self.lambda_decay,
            nonneg: self.nonneg,
            order: self.order,
            seed: self.seed,
        }
    }
}
