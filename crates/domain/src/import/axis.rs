//! How an import config asks for the rotation axis (`axis:`). The estimators reconstruct, so
//! they live with the algorithms (`prism_recon::algorithms::axis`); the estimate a scene records
//! is [`crate::scene::AxisEstimate`], with the scene's provenance.

use crate::scene::AxisMethod;
use serde::Deserialize;
use serde::de::{self, Deserializer, MapAccess, Visitor};
use std::fmt;

/// `axis:` in an import config: `auto` (a method name alone), or `{method: …, range_px: …}`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisConfig {
    pub method: AxisMethod,
    /// The search runs over the given `offset_u` ± this many detector columns (default: a tenth
    /// of the detector's width, at least 8).
    pub range_px: Option<f64>,
}

impl Default for AxisConfig {
    fn default() -> Self {
        AxisConfig {
            method: AxisMethod::Given,
            range_px: None,
        }
    }
}

impl AxisConfig {
    /// The search half-width in columns for a detector `cols` wide.
    pub fn range_for(&self, cols: usize) -> f64 {
        self.range_px.unwrap_or((cols as f64 / 10.0).max(8.0))
    }
}

impl<'de> Deserialize<'de> for AxisConfig {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct AxisVisitor;
        impl<'de> Visitor<'de> for AxisVisitor {
            type Value = AxisConfig;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(
                    "`given`, `auto`, `opposing` or `sharpness`, or a map {method, range_px}",
                )
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<AxisConfig, E> {
                let method = v.parse().map_err(E::custom)?;
                Ok(AxisConfig {
                    method,
                    range_px: None,
                })
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<AxisConfig, A::Error> {
                let mut out = AxisConfig::default();
                while let Some(key) = map.next_key::<String>()? {
                    match key.as_str() {
                        "method" => out.method = map.next_value()?,
                        "range_px" => out.range_px = Some(map.next_value()?),
                        other => {
                            return Err(de::Error::unknown_field(other, &["method", "range_px"]));
                        }
                    }
                }
                Ok(out)
            }
        }
        deserializer.deserialize_any(AxisVisitor)
    }
}
