//! What a run leaves behind, for every method alike: the run directory published as a whole
//! ([`RunDir`]), the training log (`log.jsonl`, [`log`]), the fingerprint that ties a checkpoint
//! to its scene and settings ([`fingerprint`]), the resume file ([`resume`]) and the safetensors
//! files they are written in ([`tensors`]).

pub mod fingerprint;
pub mod log;
pub mod resume;
pub mod run_dir;
pub mod tensors;

pub use run_dir::{Manifest, RunDir};
