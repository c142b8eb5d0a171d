//! R²-Gaussian's configuration (YAML `method: r2gs`): the geometry stage alone
//! ([`GeometryConfig`]), applied to every channel on its own.

use crate::Result;
use crate::gaussians::GeometryConfig;
use crate::gaussians::config::flat;
use serde::Serialize;
use std::path::Path;

/// R²-Gaussian's configuration.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct R2gsConfig {
    pub geometry: GeometryConfig,
}

/// Written as the YAML is: one flat mapping (`config.resolved.yaml`, fingerprints).
impl Serialize for R2gsConfig {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        flat::join(
            crate::Method::R2gs.name(),
            vec![serde_yaml_ng::to_value(&self.geometry)],
            s,
        )
    }
}

impl R2gsConfig {
    /// Parse and validate the flat YAML `text` of `file`; 4D-SG's keys (`stage2`,
    /// `holdout_channels`, …) are refused, since no part of R²-Gaussian reads them.
    pub fn from_yaml(text: &str, file: &Path) -> Result<Self> {
        let name = crate::Method::R2gs.name();
        flat::refuse_unknown(text, file, name, &flat::keys::<GeometryConfig>())?;
        let cfg = R2gsConfig {
            geometry: flat::read(text, file)?,
        };
        cfg.geometry.validate().map_err(|e| e.in_file(file))?;
        Ok(cfg)
    }
}
