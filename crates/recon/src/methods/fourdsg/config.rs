//! 4D-SG's configuration (YAML `method: 4dsg | 4dsg-stage1`): R²-Gaussian's configuration, the
//! geometry stage ([`GeometryConfig`]: stage 1 fits the shared geometry with it), plus 4D-SG's
//! own sections ([`SpectralConfig`]: what stage 1 fits, the spectral stage, held-out channels).
//! Both are top-level keys of one flat YAML mapping; a key neither reads is refused.

use crate::gaussians::GeometryConfig;
use crate::gaussians::config::flat;
use crate::methods::fourdsg::stage2::config::{BasisConfig, Stage2Config};
use crate::{Error, Result};
use prism_domain::scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The 4D-SG methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "crate::Method", into = "crate::Method")]
pub enum FourDsgMethod {
    /// `4dsg-stage1`: the shared geometry, then per-channel densities fitted directly on the
    /// fixed geometry (no curve model).
    Stage1,
    /// `4dsg`: stage 1 (shared geometry), then stage 2 (the spectral head predicts every
    /// Gaussian's raw density over the spectral grid).
    Full,
}

impl FourDsgMethod {
    pub fn name(self) -> &'static str {
        crate::Method::from(self).name()
    }
}

/// 4D-SG's configuration: the geometry stage and 4D-SG's own sections.
#[derive(Clone, Debug, PartialEq)]
pub struct FourDsgConfig {
    pub method: FourDsgMethod,
    /// Stage 1's geometry fit (R²-Gaussian's settings); stage 2 keeps its `lr`, `loss`,
    /// `projection` and `seed` (+1).
    pub geometry: GeometryConfig,
    pub spectral: SpectralConfig,
}

/// What 4D-SG adds to the geometry stage (YAML keys beside the geometry stage's; every field
/// optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SpectralConfig {
    /// What stage 1's shared geometry is fitted to.
    pub structural: StructuralSource,
    /// `structural: joint`: the basis stage 1 fits every channel in.
    pub joint: JointConfig,
    /// `4dsg-stage1`: iterations of the per-channel density fit on the fixed geometry (default 500).
    pub density_iterations: usize,
    /// `4dsg`: stage 2 (the spectral head) settings.
    pub stage2: Stage2Config,
    /// Channel labels left out of training entirely; 4D-SG predicts them from the curve of the
    /// observed channels and scores the prediction (`holdout.json`).
    pub holdout_channels: Vec<String>,
}

impl Default for SpectralConfig {
    fn default() -> Self {
        SpectralConfig {
            structural: StructuralSource::default(),
            joint: JointConfig::default(),
            density_iterations: 500,
            stage2: Stage2Config::default(),
            holdout_channels: Vec::new(),
        }
    }
}

impl Default for FourDsgConfig {
    fn default() -> Self {
        FourDsgConfig::new(FourDsgMethod::Full)
    }
}

/// Written as the YAML is: one flat mapping (`config.resolved.yaml`, fingerprints).
impl Serialize for FourDsgConfig {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        flat::join(
            self.method.name(),
            vec![
                serde_yaml_ng::to_value(&self.geometry),
                serde_yaml_ng::to_value(&self.spectral),
            ],
            s,
        )
    }
}

impl FourDsgConfig {
    /// A configuration for `method` with every default.
    pub fn new(method: FourDsgMethod) -> Self {
        FourDsgConfig {
            method,
            geometry: GeometryConfig::default(),
            spectral: SpectralConfig::default(),
        }
    }

    /// Parse and validate the flat YAML `text` of `file` (`method` is read first, by
    /// [`crate::MethodConfig`]).
    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let method: MethodKey = flat::read(text, file)?;
        let known = [
            flat::keys::<GeometryConfig>(),
            flat::keys::<SpectralConfig>(),
        ]
        .concat();
        flat::refuse_unknown(text, file, method.method.name(), &known)?;
        let cfg = FourDsgConfig {
            method: method.method,
            geometry: flat::read(text, file)?,
            spectral: flat::read(text, file)?,
        };
        cfg.validate().map_err(|e| e.in_file(file))?;
        Ok(cfg)
    }

    pub fn validate(&self) -> Result<()> {
        self.geometry.validate()?;
        let s = &self.spectral;
        match self.method {
            FourDsgMethod::Stage1 if s.density_iterations == 0 => {
                Err(Error::invalid("density_iterations", "must be at least 1"))
            }
            FourDsgMethod::Full => s.stage2.validate(),
            FourDsgMethod::Stage1 => Ok(()),
        }
    }

    /// Indices of the held-out channels in `scene`; errors name unknown labels, held-out
    /// channels at the ends of the spectral grid (they would need extrapolation), or too few
    /// observed channels left.
    pub fn holdout_indices(&self, scene: &Scene) -> Result<Vec<usize>> {
        let labels = &self.spectral.holdout_channels;
        if labels.is_empty() {
            return Ok(Vec::new());
        }
        let m = scene.n_channels();
        let mut out = Vec::new();
        for (i, label) in labels.iter().enumerate() {
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
}

/// The `method` key of a 4D-SG YAML.
#[derive(Deserialize)]
struct MethodKey {
    method: FourDsgMethod,
}

/// Stage 1's joint fit (`structural: joint`; YAML `joint:`, every field optional): while the
/// shared geometry is fitted to every channel's projections, each Gaussian carries one density
/// per basis material and every channel is formed from them by the physics
/// ([`crate::methods::fourdsg::heads::BasisHead`]). Two materials of different effective atomic number span,
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
