//! Every reconstruction method behind one configuration type: the YAML's `method` picks the
//! classic (`fdk | sart | cgls`) or the Gaussian (`r2gs | 4dsg-stage1`) parser and runner.

use crate::classic::recon::{self, ReconConfig, ReconReport};
use crate::gaussian::{self, GaussianConfig};
use crate::scene::Scene;
use crate::{Error, Result};
use burn::tensor::Device;
use std::path::Path;

/// A parsed run configuration of any method.
#[derive(Clone, Debug, PartialEq)]
pub enum MethodConfig {
    Classic(ReconConfig),
    Gaussian(Box<GaussianConfig>),
}

impl MethodConfig {
    /// Parse YAML text; errors name `file` and the field.
    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let value: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(text).map_err(|e| crate::yaml::error(file, &e))?;
        let method = value.get("method").and_then(|m| m.as_str());
        match method {
            Some("fdk" | "sart" | "cgls") => {
                ReconConfig::from_yaml(text, file).map(MethodConfig::Classic)
            }
            Some("r2gs" | "4dsg-stage1" | "4dsg") => {
                GaussianConfig::from_yaml(text, file).map(|c| MethodConfig::Gaussian(Box::new(c)))
            }
            Some(other) => Err(Error::field(
                file,
                "method",
                format!(
                    "unknown method `{other}` (expected fdk, sart, cgls, r2gs, 4dsg-stage1 or 4dsg)"
                ),
            )),
            None => Err(Error::field(file, "method", "missing (a string)")),
        }
    }

    /// Read and parse a YAML file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_yaml(&text, path)
    }

    /// Reconstruct `scene` into `out_dir`; Gaussian methods run on `device`.
    pub fn run(
        &self,
        scene: &Scene,
        out_dir: &Path,
        device: &Device,
    ) -> Result<Option<ReconReport>> {
        match self {
            MethodConfig::Classic(c) => recon::run(c, scene, out_dir),
            MethodConfig::Gaussian(c) => gaussian::run::run(c, scene, out_dir, device),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_method_picks_the_parser_and_errors_name_the_file() {
        let f = Path::new("run.yaml");
        assert!(matches!(
            MethodConfig::from_yaml("method: sart\niterations: 2\n", f).unwrap(),
            MethodConfig::Classic(_)
        ));
        assert!(matches!(
            MethodConfig::from_yaml("method: 4dsg-stage1\niterations: 5\n", f).unwrap(),
            MethodConfig::Gaussian(_)
        ));
        let e = MethodConfig::from_yaml("method: nerf\n", f)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("run.yaml") && e.contains("method") && e.contains("nerf"),
            "{e}"
        );
        let e = MethodConfig::from_yaml("method: r2gs\nlr: {position: 3}\n", f)
            .unwrap_err()
            .to_string();
        assert!(e.contains("run.yaml") && e.contains("lr"), "{e}");
        let e = MethodConfig::from_yaml("method: r2gs\niterations: 0\n", f)
            .unwrap_err()
            .to_string();
        assert!(e.contains("iterations"), "{e}");
        let e = MethodConfig::from_yaml("method: r2gs\nprojection: {cutoff: 0}\n", f)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("run.yaml") && e.contains("projection.cutoff"),
            "{e}"
        );
        let e = MethodConfig::from_yaml("method: r2gs\nprojection: {mode: curved}\n", f)
            .unwrap_err()
            .to_string();
        assert!(e.contains("run.yaml") && e.contains("curved"), "{e}");
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
