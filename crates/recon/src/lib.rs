//! Prism's reconstruction methods and the run pipeline that writes, scores and reports them.
//!
//! Data flow of a run ([`pipeline::run`]), one folder per stage:
//!
//! * [`classic`]: FDK, the SART family and CGLS, each channel independently;
//! * [`init`]: an FDK of the training views → initial Gaussians ([`gaussian`] holds the
//!   representation: parameters, activations, Adam state, the normalised world, model files);
//! * [`train`]: the [`train::Trainer`] (one iteration per `step`) and the loop that schedules,
//!   evaluates and logs it; R²-Gaussian trains it per channel;
//! * [`stage1`]: 4D-SG's shared geometry from the structural projections (and its checkpoint);
//! * [`stage2`]: the spectral stage: GSC-Net or the MLP predicts every Gaussian's density curve
//!   (or per-channel densities on the fixed geometry);
//! * [`naf`]: NAF, a hash-grid neural field per channel (the field is `prism-field`);
//! * [`query`]: the trained curves at any spectral coordinate, held-out channels scored;
//! * [`evaluate`]: volumes scored against the scene's references (`metrics.json`);
//! * [`report`]: finished runs side by side (`prism report`);
//! * [`pipeline`]: the one entry point [`pipeline::run`], the run directory
//!   ([`pipeline::RunDir`], published atomically) and the stage-2 ablations.
//!
//! The domain (scenes, geometry, physics, the voxel projector, metrics) is `prism-domain`.
//! Progress goes to a [`prism_domain::observe::Observer`]; nothing here prints.

pub mod classic;
pub mod error;
pub mod evaluate;
pub mod gaussian;
pub mod init;
pub mod method;
pub mod naf;
pub mod pipeline;
pub mod query;
pub mod report;
pub mod stage1;
pub mod stage2;
pub mod train;

pub use error::{Error, Result};
pub use method::{Method, MethodConfig};
