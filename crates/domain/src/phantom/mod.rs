//! Phantoms: analytic ellipsoid phantoms with material fractions ([`SpectralPhantom`], built-in
//! table in [`SpectralPhantom::builtin`]), and material volumes from clinical CT in Hounsfield
//! units ([`hu`]).

mod builtin;
pub mod ellipsoid;
pub mod hu;
pub mod spectral;

pub use builtin::{BUILTIN_CALCIUM_MG_ML, BUILTIN_IODINE_MG_ML};
pub use ellipsoid::Ellipsoid;
pub use hu::{HuMapping, HuVolume, hu_material_volumes};
pub use spectral::{Component, MaterialVolumes, SpectralPhantom, iodine_fraction};
