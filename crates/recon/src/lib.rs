//! Prism's reconstruction methods and the run pipeline that writes, scores and reports them.
//!
//! Method first: [`methods`] holds one folder per method ([`methods::classic`],
//! [`methods::r2gs`], [`methods::fourdsg`], [`methods::naf`]), each with its configuration, its
//! loop, its checkpoints and its queries, and the one registry of methods ([`Method`],
//! [`MethodConfig`]). Below them, the floor they share (nothing here imports a method):
//!
//! * [`algorithms`]: FDK, the SART family and CGLS as operators on one channel's projections;
//! * [`init`]: an FDK of the training views → initial Gaussians, or NAF's density scale;
//! * [`gaussians`]: the Gaussian representation (parameters, activations, Adam, the normalised
//!   world, volumes, files), its spectral heads and the training loop ([`gaussians::train`]);
//! * [`record`]: the run directory, `log.jsonl`, fingerprints and resume files;
//! * [`evaluate`]: volumes scored against the scene's references (`metrics.json`);
//! * [`setup`]: what a method's run is given ([`setup::RunOptions`]) and the scene as it sees it;
//! * [`device`]: where a trained method runs.
//!
//! Above them: [`pipeline`], the one entry point [`pipeline::run`] (config → method → run
//! directory), [`report`], finished runs side by side (`prism report`), and [`decompose`],
//! basis-material maps and VMIs of a finished run (`prism decompose`).
//!
//! The domain (scenes, geometry, physics, the voxel projector, metrics) is `prism-domain`.
//! Progress goes to a [`prism_domain::observe::Observer`]; nothing here prints.

pub mod algorithms;
pub mod decompose;
pub mod device;
pub mod error;
pub mod evaluate;
pub mod gaussians;
pub mod init;
pub mod methods;
pub mod pipeline;
pub mod record;
pub mod report;
pub mod setup;

pub use error::{Error, Result};
pub use methods::{Method, MethodConfig};
