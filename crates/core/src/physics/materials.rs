//! Materials known to Prism.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// A material of the embedded NIST table. Names in files are the snake-case forms below.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Material {
    Water,
    Air,
    SoftTissue,
    CorticalBone,
    Adipose,
    Iodine,
    Calcium,
    Aluminium,
}

impl Material {
    /// Every material, in table order.
    pub const ALL: [Material; 8] = [
        Material::Water,
        Material::Air,
        Material::SoftTissue,
        Material::CorticalBone,
        Material::Adipose,
        Material::Iodine,
        Material::Calcium,
        Material::Aluminium,
    ];

    /// The snake-case name used in files.
    pub fn name(self) -> &'static str {
        match self {
            Material::Water => "water",
            Material::Air => "air",
            Material::SoftTissue => "soft_tissue",
            Material::CorticalBone => "cortical_bone",
            Material::Adipose => "adipose",
            Material::Iodine => "iodine",
            Material::Calcium => "calcium",
            Material::Aluminium => "aluminium",
        }
    }

    /// Parse a snake-case name; the error lists the known names.
    pub fn from_name(name: &str) -> Result<Material> {
        Material::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                let known: Vec<_> = Material::ALL.iter().map(|m| m.name()).collect();
                Error::invalid(
                    "material",
                    format!("unknown material `{name}` (known: {})", known.join(", ")),
                )
            })
    }
}
