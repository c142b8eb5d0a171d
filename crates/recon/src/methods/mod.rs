//! The reconstruction methods, one folder each, and the one registry of them: the YAML's
//! `method:` is read as a [`Method`] first, which picks the configuration type of its family.
//! The config loader (and through it the CLI) and the experiment planner read the methods from here.
//!
//! * [`classic`]: FDK, SART, CGLS per channel, and TV-regularised least squares with the
//!   channels coupled (the algorithms are [`crate::algorithms`]);
//! * [`r2gs`]: R²-Gaussian, one set of Gaussians per channel;
//! * [`fourdsg`]: 4D-SG, shared geometry then a spectral head;
//! * [`naf`]: NAF, a hash-grid neural field per channel.
//!
//! Each imports the shared floor ([`crate::gaussians`], [`crate::record`], [`crate::evaluate`],
//! [`crate::init`], [`crate::device`]) and never another method.

pub mod classic;
pub mod fourdsg;
pub mod naf;
pub mod r2gs;

use crate::device::DeviceChoice;
use crate::gaussians::GeometryConfig;
use crate::{Error, Result};
use classic::{ClassicConfig, ClassicMethod};
use fourdsg::{FourDsgConfig, FourDsgMethod};
use naf::{NafConfig, NafMethod};
use prism_domain::yaml::Overrides;
use r2gs::R2gsConfig;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A reconstruction method, as a config's `method:` names it. The one list of methods: their
/// names ([`Method::name`]) are written here only; each family's enum ([`ClassicMethod`],
/// [`FourDsgMethod`], [`NafMethod`]) reads and writes its members through this one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "&'static str")]
pub enum Method {
    Fdk,
    Sart,
    Cgls,
    Tv,
    R2gs,
    FourDsgStage1,
    FourDsg,
    Naf,
}

/// The families of methods, each with its configuration type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    Classic(ClassicMethod),
    /// R²-Gaussian.
    R2gs,
    FourDsg(FourDsgMethod),
    /// Neural attenuation fields.
    Naf,
}

impl Method {
    pub fn family(self) -> Family {
        match self {
            Method::Fdk => Family::Classic(ClassicMethod::Fdk),
            Method::Sart => Family::Classic(ClassicMethod::Sart),
            Method::Cgls => Family::Classic(ClassicMethod::Cgls),
            Method::Tv => Family::Classic(ClassicMethod::Tv),
            Method::R2gs => Family::R2gs,
            Method::FourDsgStage1 => Family::FourDsg(FourDsgMethod::Stage1),
            Method::FourDsg => Family::FourDsg(FourDsgMethod::Full),
            Method::Naf => Family::Naf,
        }
    }

    /// Every method (an unknown name's error lists them in this order).
    pub const ALL: [Method; 8] = [
        Method::Fdk,
        Method::Sart,
        Method::Cgls,
        Method::Tv,
        Method::R2gs,
        Method::FourDsgStage1,
        Method::FourDsg,
        Method::Naf,
    ];

    /// The name configs, logs and `metrics.json` use.
    pub fn name(self) -> &'static str {
        match self {
            Method::Fdk => "fdk",
            Method::Sart => "sart",
            Method::Cgls => "cgls",
            Method::Tv => "tv",
            Method::R2gs => "r2gs",
            Method::FourDsgStage1 => "4dsg-stage1",
            Method::FourDsg => "4dsg",
            Method::Naf => "naf",
        }
    }

    /// The method named `name`, or an error listing every name.
    pub fn from_name(name: &str) -> std::result::Result<Self, String> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                let names: Vec<_> = Method::ALL.iter().map(|m| m.name()).collect();
                format!(
                    "unknown method `{name}`, expected one of {}",
                    names.join(", ")
                )
            })
    }

    /// Whether a run is trained iteratively and can be interrupted and resumed
    /// (`crate::gaussians::train::checkpoints`, `crate::methods::naf::resume`): the Gaussian methods and NAF.
    pub fn trains(self) -> bool {
        !matches!(self.family(), Family::Classic(_))
    }

    /// Whether the method trains 4D-SG's shared geometry (and can continue from its checkpoint).
    pub fn has_shared_geometry(self) -> bool {
        matches!(self, Method::FourDsgStage1 | Method::FourDsg)
    }
}

impl TryFrom<String> for Method {
    type Error = String;
    fn try_from(name: String) -> std::result::Result<Self, String> {
        Method::from_name(&name)
    }
}

impl From<Method> for &'static str {
    fn from(m: Method) -> Self {
        m.name()
    }
}

/// A family's member from a [`Method`], or an error naming the method and the family.
fn member<T>(
    m: Method,
    family: &str,
    of: impl Fn(Family) -> Option<T>,
) -> std::result::Result<T, String> {
    of(m.family()).ok_or_else(|| format!("`{}` is not {family} method", m.name()))
}

impl TryFrom<Method> for ClassicMethod {
    type Error = String;
    fn try_from(m: Method) -> std::result::Result<Self, String> {
        member(m, "a classic", |f| match f {
            Family::Classic(c) => Some(c),
            _ => None,
        })
    }
}

impl TryFrom<Method> for FourDsgMethod {
    type Error = String;
    fn try_from(m: Method) -> std::result::Result<Self, String> {
        member(m, "a 4D-SG", |f| match f {
            Family::FourDsg(g) => Some(g),
            _ => None,
        })
    }
}

impl TryFrom<Method> for NafMethod {
    type Error = String;
    fn try_from(m: Method) -> std::result::Result<Self, String> {
        member(m, "the NAF", |f| match f {
            Family::Naf => Some(NafMethod::Naf),
            _ => None,
        })
    }
}

impl From<NafMethod> for Method {
    fn from(_: NafMethod) -> Self {
        Method::Naf
    }
}

impl From<ClassicMethod> for Method {
    fn from(m: ClassicMethod) -> Self {
        match m {
            ClassicMethod::Fdk => Method::Fdk,
            ClassicMethod::Sart => Method::Sart,
            ClassicMethod::Cgls => Method::Cgls,
            ClassicMethod::Tv => Method::Tv,
        }
    }
}

impl From<FourDsgMethod> for Method {
    fn from(m: FourDsgMethod) -> Self {
        match m {
            FourDsgMethod::Stage1 => Method::FourDsgStage1,
            FourDsgMethod::Full => Method::FourDsg,
        }
    }
}

/// A parsed run configuration of any method.
#[derive(Clone, Debug, PartialEq)]
pub enum MethodConfig {
    Classic(ClassicConfig),
    R2gs(Box<R2gsConfig>),
    FourDsg(Box<FourDsgConfig>),
    Naf(Box<NafConfig>),
}

impl From<R2gsConfig> for MethodConfig {
    fn from(c: R2gsConfig) -> Self {
        MethodConfig::R2gs(Box::new(c))
    }
}

impl From<FourDsgConfig> for MethodConfig {
    fn from(c: FourDsgConfig) -> Self {
        MethodConfig::FourDsg(Box::new(c))
    }
}

impl MethodConfig {
    /// Parse YAML text; errors name `file` and the field.
    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let value: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(text).map_err(|e| prism_domain::yaml::error(file, &e))?;
        let Some(method) = value.get("method") else {
            return Err(Error::field(file, "method", "missing (a string)"));
        };
        let method: Method = serde_yaml_ng::from_value(method.clone())
            .map_err(|e| Error::field(file, "method", e.to_string()))?;
        match method.family() {
            Family::Classic(_) => ClassicConfig::from_yaml(text, file).map(MethodConfig::Classic),
            Family::R2gs => {
                R2gsConfig::from_yaml(text, file).map(|c| MethodConfig::R2gs(Box::new(c)))
            }
            Family::FourDsg(_) => {
                FourDsgConfig::from_yaml(text, file).map(|c| MethodConfig::FourDsg(Box::new(c)))
            }
            Family::Naf => NafConfig::from_yaml(text, file).map(|c| MethodConfig::Naf(Box::new(c))),
        }
    }

    /// Read and parse a YAML file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        Self::load_with(path, &Overrides::default())
    }

    /// Read a YAML file, apply `--set` overrides, parse and validate; errors name the file, the
    /// field, and the override when it set that field.
    pub fn load_with(path: impl AsRef<Path>, overrides: &Overrides) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        if overrides.is_empty() {
            return Self::from_yaml(&text, path);
        }
        let value = overrides.apply_to_text(&text, path)?;
        let text =
            serde_yaml_ng::to_string(&value).map_err(|e| Error::field(path, ".", e.to_string()))?;
        Self::from_yaml(&text, path).map_err(|e| match e {
            Error::Domain(d) => Error::Domain(overrides.explain(d)),
            other => other,
        })
    }

    pub fn method(&self) -> Method {
        match self {
            MethodConfig::Classic(c) => c.method.into(),
            MethodConfig::R2gs(_) => Method::R2gs,
            MethodConfig::FourDsg(c) => c.method.into(),
            MethodConfig::Naf(_) => Method::Naf,
        }
    }

    /// The geometry stage's settings of a Gaussian method (R²-Gaussian, 4D-SG).
    pub fn geometry(&self) -> Option<&GeometryConfig> {
        match self {
            MethodConfig::R2gs(c) => Some(&c.geometry),
            MethodConfig::FourDsg(c) => Some(&c.geometry),
            MethodConfig::Classic(_) | MethodConfig::Naf(_) => None,
        }
    }

    /// Where the method runs (classic methods: always the CPU).
    pub fn device(&self) -> DeviceChoice {
        match self {
            MethodConfig::Classic(_) => DeviceChoice::Cpu,
            MethodConfig::R2gs(c) => c.geometry.device,
            MethodConfig::FourDsg(c) => c.geometry.device,
            MethodConfig::Naf(c) => c.device,
        }
    }

    /// Run a Gaussian or NAF method on `device` instead of its configured device (classic
    /// methods always run on the CPU).
    pub fn set_device(&mut self, device: DeviceChoice) {
        match self {
            MethodConfig::Classic(_) => {}
            MethodConfig::R2gs(c) => c.geometry.device = device,
            MethodConfig::FourDsg(c) => c.geometry.device = device,
            MethodConfig::Naf(c) => c.device = device,
        }
    }

    /// The configuration with every default made explicit (`config.resolved.yaml`).
    pub fn resolved_yaml(&self) -> Result<String> {
        let yaml = match self {
            MethodConfig::Classic(c) => serde_yaml_ng::to_string(&c.resolved()),
            MethodConfig::R2gs(c) => serde_yaml_ng::to_string(c),
            MethodConfig::FourDsg(c) => serde_yaml_ng::to_string(c),
            MethodConfig::Naf(c) => serde_yaml_ng::to_string(c),
        };
        yaml.map_err(|e| Error::invalid("config", e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_method_picks_the_parser_and_errors_name_the_file() {
        let f = Path::new("run.yaml");
        let c = MethodConfig::from_yaml("method: sart\niterations: 2\n", f).unwrap();
        assert!(matches!(c, MethodConfig::Classic(_)));
        assert_eq!(c.method(), Method::Sart);
        let c = MethodConfig::from_yaml("method: 4dsg-stage1\niterations: 5\n", f).unwrap();
        assert!(matches!(c, MethodConfig::FourDsg(_)));
        assert_eq!(c.method(), Method::FourDsgStage1);
        for (yaml, needles) in [
            (
                "method: nerf\n",
                &["run.yaml", "method", "nerf", "4dsg-stage1"][..],
            ),
            ("iterations: 3\n", &["run.yaml", "method", "missing"]),
            ("method: r2gs\nlr: {position: 3}\n", &["run.yaml", "lr"]),
            ("method: r2gs\niterations: 0\n", &["iterations"]),
            (
                "method: r2gs\nprojection: {cutoff: 0}\n",
                &["run.yaml", "projection.cutoff"],
            ),
            (
                "method: r2gs\nprojection: {mode: curved}\n",
                &["run.yaml", "curved"],
            ),
            ("method: sart\nfilter: triangle\n", &["run.yaml", "filter"]),
            (
                "method: naf\nrays_per_batch: 0\n",
                &["run.yaml", "rays_per_batch"],
            ),
            (
                "method: naf\nfield: {hash_grid: {levels: 0}}\n",
                &["run.yaml", "field.hash_grid.levels"],
            ),
            ("method: naf\nfield: {depth: 3}\n", &["run.yaml", "depth"]),
            // A flat config refuses a key no part of the method reads, naming it: a typo, or
            // 4D-SG's own sections under R²-Gaussian.
            (
                "method: 4dsg\niteration: 3\n",
                &["run.yaml", "iteration", "`4dsg`"],
            ),
            (
                "method: r2gs\nstage2: {iterations: 3}\n",
                &["run.yaml", "stage2", "`r2gs` has no setting"],
            ),
            // Errors inside either part keep their field paths.
            (
                "method: 4dsg\nstage2: {iterations: many}\n",
                &["run.yaml", "stage2.iterations"],
            ),
            ("method: 4dsg\nlr: {position: 3}\n", &["run.yaml", "lr"]),
            (
                "method: 4dsg-stage1\ndensity_iterations: 0\n",
                &["run.yaml", "density_iterations"],
            ),
        ] {
            let e = MethodConfig::from_yaml(yaml, f).unwrap_err().to_string();
            for n in needles {
                assert!(e.contains(n), "`{n}` not in: {e}");
            }
        }
    }

    #[test]
    fn partial_sections_take_the_rest_from_their_defaults() {
        let f = Path::new("run.yaml");
        let yaml = "method: 4dsg\ninit: {n_points: 300}\ndensify: {every: 50}\n\
                    stage2: {freeze: {position: true}}\nloss: {lambda_tv: 0}\n";
        let four = MethodConfig::from_yaml(yaml, f).unwrap();
        let MethodConfig::FourDsg(c) = &four else {
            panic!("a 4D-SG config");
        };
        let d = FourDsgConfig::default();
        let (g, dg) = (&c.geometry, &d.geometry);
        assert_eq!(g.init.n_points, 300);
        assert_eq!(g.init.threshold, dg.init.threshold);
        let densify = g.densify.as_ref().unwrap();
        assert_eq!(densify.every, 50);
        assert_eq!(densify.until, dg.densify.as_ref().unwrap().until);
        let s2 = &c.spectral.stage2;
        assert!(s2.freeze.position && !s2.freeze.scale);
        assert_eq!(s2.iterations, d.spectral.stage2.iterations);
        assert_eq!(
            (g.loss.lambda_tv, g.loss.lambda_dssim),
            (0.0, dg.loss.lambda_dssim)
        );
        // `densify: null` turns densification off; an absent section keeps the default.
        let r2 = MethodConfig::from_yaml("method: r2gs\ndensify: null\n", f).unwrap();
        let MethodConfig::R2gs(c) = &r2 else {
            panic!("an R²-Gaussian config");
        };
        assert!(c.geometry.densify.is_none());
        // The resolved config reads back as the same config, one flat mapping.
        for config in [four, r2] {
            let resolved = config.resolved_yaml().unwrap();
            assert!(resolved.starts_with("method: "), "{resolved}");
            assert_eq!(MethodConfig::from_yaml(&resolved, f).unwrap(), config);
        }
    }

    #[test]
    fn every_shipped_recon_config_parses() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/recon");
        let mut n = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "yaml") {
                MethodConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
                n += 1;
            }
        }
        assert!(n >= 7, "{n} configs");
    }
}
