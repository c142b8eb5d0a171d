//! X-ray physics: materials and their attenuation, tube spectra, channel synthesis, noise.
//!
//! Units: energies in keV, μ/ρ in cm²/g, densities in g/cm³, linear attenuation μ in mm⁻¹,
//! path lengths in mm, projections as dimensionless line integrals.

pub mod attenuation;
pub mod channel;
pub mod materials;
pub mod noise;
pub mod spectrum;

pub use channel::ChannelSpec;
pub use materials::Material;
pub use noise::{COUNT_FLOOR, NoiseModel, add_noise};
pub use spectrum::{Filtration, Spectrum};
