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
    Iron,
    Titanium,
}

impl Material {
    /// Every material, in table order.
    pub const ALL: [Material; 10] = [
        Material::Water,
        Material::Air,
        Material::SoftTissue,
        Material::CorticalBone,
        Material::Adipose,
        Material::Iodine,
        Material::Calcium,
        Material::Aluminium,
        Material::Iron,
        Material::Titanium,
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
            Material::Iron => "iron",
            Material::Titanium => "titanium",
        }
    }

    /// Nominal density of the pure material, g/cm³ (the values of the embedded NIST table:
    /// water 1, dry air at 20 °C, ICRU-44 tissues, elemental solids; iron and titanium from the CRC
    /// handbook, for metal inserts).
    pub fn density(self) -> f64 {
        match self {
            Material::Water => 1.0,
            Material::Air => 0.001205,
            Material::SoftTissue => 1.06,
            Material::CorticalBone => 1.92,
            Material::Adipose => 0.95,
            Material::Iodine => 4.93,
            Material::Calcium => 1.55,
            Material::Aluminium => 2.699,
            Material::Iron => 7.874,
            Material::Titanium => 4.506,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_name_names_the_field() {
        for m in Material::ALL {
            assert_eq!(Material::from_name(m.name()).unwrap(), m);
            let yaml = serde_yaml_ng::to_string(&m).unwrap();
            assert_eq!(yaml.trim(), m.name());
        }
        let msg = Material::from_name("bone").unwrap_err().to_string();
        assert!(
            msg.contains("`material`") && msg.contains("cortical_bone"),
            "{msg}"
        );
    }

    #[test]
    fn all_is_in_declaration_order() {
        // The attenuation table is indexed by `m as usize`.
        for (i, m) in Material::ALL.iter().enumerate() {
            assert_eq!(*m as usize, i);
        }
    }
}
