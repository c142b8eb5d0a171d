//! The spectral heads a Gaussian stage can train on top of one shared geometry (4D-SG's
//! spectral stage trains one of them): a curve model ([`CurveFit`]: GSC-Net or the MLP predicts
//! every Gaussian's raw density along the spectral axis) or basis-material densities
//! ([`BasisHead`]: each channel formed by the simulator's forward model), and their YAML
//! section ([`config`], `stage2:`); and the channels' measured gains ([`gains`]).

pub mod basis;
pub mod config;
pub mod curve;
pub mod gains;

pub use basis::BasisHead;
pub use config::{BasisConfig, Freeze, Stage2Config};
pub use curve::CurveFit;
