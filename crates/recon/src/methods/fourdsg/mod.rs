//! 4D-SG (`method: 4dsg`, and `4dsg-stage1` for its geometry stage alone): one set of 3D
//! Gaussians shared by every energy channel, then a spectral head on it.
//!
//! * [`config`]: its configuration, R²-Gaussian's geometry stage plus 4D-SG's own sections;
//! * [`stage1`]: the shared geometry fitted to the structural projections, and its checkpoint
//!   (`geometry.safetensors`, `--from-geometry`);
//! * [`stage2`]: the spectral stage on that geometry (GSC-Net / MLP curves, the basis-material
//!   head, or per-channel densities), with the heads of [`crate::gaussians::spectral`];
//! * [`run`]: both stages in a run directory, held-out channels predicted and scored;
//! * [`query`]: a trained model at any spectral coordinate or energy, held-out channels;
//! * [`ablation`]: stage-2 variants trained from one stage 1 (`prism ablate`).
//!
//! Training and checkpoints are the shared Gaussian loop's ([`crate::gaussians::train`]).

pub mod ablation;
pub mod config;
pub mod query;
pub(crate) mod run;
pub mod stage1;
pub mod stage2;

pub use config::{FourDsgConfig, FourDsgMethod, JointConfig, SpectralConfig, StructuralSource};
