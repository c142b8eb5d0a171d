//! The rotation axis of a measured scan: how the import config asks for it (`axis:`) and the
//! estimate a scene records in its provenance. The estimators themselves reconstruct, so they
//! live with the algorithms (`prism_recon::algorithms::axis`).
//!
//! The axis is stated as the detector's `offset_u` (mm): the axis projects onto column
//! `(cols − 1)/2 − offset_u / pitch_u` (`docs/geometry.md`), so an axis seen 24 columns left of
//! the detector centre is `offset_u = +24·pitch_u`.

use serde::de::{self, Deserializer, MapAccess, Visitor};
use serde::{Deserialize, Serialize};
use std::fmt;

/// How an estimator finds the axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AxisMethod {
    /// The geometry's `offset_u` as given: nothing is estimated.
    #[default]
    Given,
    /// `opposing` on a scan that covers a full turn, else `sharpness`.
    Auto,
    /// Every ray against its conjugate ray (the same line measured from the other side),
    /// interpolated from the views around it: the offset that makes the two agree best. Parallel
    /// beam pairs θ with θ + π; fan and cone beams (their central row) pair a ray at fan angle γ
    /// with θ + π + 2γ. Needs the conjugates measured: a full turn.
    Opposing,
    /// The central slice filtered-backprojected at each candidate offset; the offset whose image
    /// has the least histogram entropy (Donath et al. 2006): a misplaced axis doubles and smears
    /// edges, which spreads the histogram. Any angular range.
    Sharpness,
}

impl AxisMethod {
    /// Its name in prose.
    pub fn describe(self) -> &'static str {
        match self {
            AxisMethod::Given => "the given geometry",
            AxisMethod::Auto => "automatic choice",
            AxisMethod::Opposing => "opposing views",
            AxisMethod::Sharpness => "sharpness (entropy)",
        }
    }
}

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
                let method = AxisMethod::deserialize(de::value::StrDeserializer::<E>::new(v))?;
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

/// An estimated rotation axis, as a scene's provenance records it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisEstimate {
    /// `opposing` or `sharpness`.
    pub method: AxisMethod,
    /// The estimate: the detector's `offset_u`, mm, and in columns (`offset_u / pitch_u`).
    pub offset_u: f64,
    pub offset_px: f64,
    /// The offset the geometry gave (mm), which the search was centred on.
    pub given_offset_u: f64,
    /// Standard error in columns: the spread of the estimates from `subsets.len()` disjoint view
    /// subsets (views `k ≡ j mod n`), divided by √n.
    pub uncertainty_px: f64,
    /// Those subsets' estimates, columns.
    pub subsets: Vec<f64>,
    /// The views and detector row(s) it was estimated from.
    pub views: usize,
    pub rows: String,
}

impl AxisEstimate {
    /// One line for logs and summaries.
    pub fn describe(&self) -> String {
        format!(
            "offset_u = {:.4} mm ({:+.3} ± {:.3} columns) by {} over {} views, {}; given {:.4} mm",
            self.offset_u,
            self.offset_px,
            self.uncertainty_px,
            self.method.describe(),
            self.views,
            self.rows,
            self.given_offset_u
        )
    }
}
