//! 4D-SG (`method: 4dsg`, and `4dsg-stage1` for its geometry stage alone): one set of 3D
//! Gaussians shared by every energy channel, then a spectral head on it.
//!
//! * [`config`]: its configuration, R²-Gaussian's geometry stage plus 4D-SG's own sections;
//! * [`stage1`]: the shared geometry fitted to the structural projections, and its checkpoint
//!   (`geometry.safetensors`, `--from-geometry`);
//! * [`heads`]: the spectral heads, GSC-Net / MLP curves ([`heads::CurveFit`]) and the
//!   basis-material head ([`heads::BasisHead`], also joint stage 1's);
//! * [`stage2`]: the spectral stage on that geometry (a head, or per-channel densities) and its
//!   YAML section;
//! * [`run`]: both stages in a run directory, held-out channels predicted and scored;
//! * [`query`]: a trained model at any spectral coordinate or energy, held-out channels;
//! * [`ablation`]: stage-2 variants trained from one stage 1 (`prism ablate`).
//!
//! Training and checkpoints are the shared Gaussian loop's ([`crate::gaussians::train`]), which
//! trains the heads through its `DensityNet` and `ChannelMix` shapes.

pub mod ablation;
pub mod config;
pub mod heads;
pub mod query;
pub(crate) mod run;
pub mod stage1;
pub mod stage2;

pub use config::{FourDsgConfig, FourDsgMethod, JointConfig, SpectralConfig, StructuralSource};
