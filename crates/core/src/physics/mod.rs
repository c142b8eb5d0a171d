//! X-ray physics: materials and their attenuation, tube spectra, channel synthesis, noise.

pub mod materials;

pub use materials::Material;
