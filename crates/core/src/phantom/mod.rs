//! Phantoms: analytic ellipsoid phantoms with material fractions, and material volumes from
//! clinical CT in Hounsfield units.

pub mod ellipsoid;

pub use ellipsoid::Ellipsoid;
