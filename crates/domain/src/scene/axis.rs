//! The rotation axis a scene's provenance records when an import estimated it
//! (`prism import` with `axis:`; `docs/import.md`, "Rotation axis").
//!
//! The axis is stated as the detector's `offset_u` (mm): the axis projects onto column
//! `(cols − 1)/2 − offset_u / pitch_u` (`docs/geometry.md`), so an axis seen 24 columns left of
//! the detector centre is `offset_u = +24·pitch_u`.

use serde::de;
use serde::{Deserialize, Serialize};

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

impl std::str::FromStr for AxisMethod {
    type Err = String;

    /// The config's names: `given`, `auto`, `opposing`, `sharpness`.
    fn from_str(s: &str) -> Result<Self, String> {
        AxisMethod::deserialize(de::value::StrDeserializer::<de::value::Error>::new(s))
            .map_err(|_| format!("`{s}`: expected given, auto, opposing or sharpness"))
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
