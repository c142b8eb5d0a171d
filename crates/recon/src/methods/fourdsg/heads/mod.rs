//! The spectral heads 4D-SG trains on its one shared geometry: a curve model ([`CurveFit`]:
//! GSC-Net or the MLP predicts every Gaussian's raw density along the spectral axis, trained as
//! the loop's [`DensityNet`](crate::gaussians::train::DensityNet)) or basis-material densities
//! ([`BasisHead`]: each channel formed by the simulator's forward model, the loop's
//! [`ChannelMix`](crate::gaussians::train::ChannelMix); also joint stage 1's head). Their YAML
//! section is stage 2's ([`super::stage2::config`]).

pub mod basis;
pub mod curve;

pub use basis::BasisHead;
pub use curve::CurveFit;
