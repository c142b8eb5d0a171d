//! The reconstruction crate's error: the domain's errors (a file, a field), the render ops' and
//! the curve model's, and a training stage that diverged.

use prism_domain::error::Error as DomainError;
use std::path::PathBuf;

/// Result alias used throughout `prism-recon`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file, a field or a value of the input (see [`prism_domain::Error`]).
    #[error(transparent)]
    Domain(#[from] DomainError),
    /// A render op refused its inputs.
    #[error("render: {0}")]
    Render(#[from] prism_render::RenderError),
    /// The curve model (GSC-Net or the MLP) refused its inputs.
    #[error("curve model: {0}")]
    CurveModel(#[from] prism_gscnet::Error),
    /// A training stage's loss stopped being finite.
    #[error("stage `{stage}` diverged at iteration {iter}: {detail}")]
    Diverged {
        stage: String,
        iter: usize,
        detail: String,
    },
    /// The run was asked to stop (SIGINT / SIGTERM) and saved its state.
    #[error(
        "interrupted in `{stage}` after iteration {iter}; the run's state is saved in `{}`: \
         run the same command with --resume to continue",
        checkpoint.display()
    )]
    Interrupted {
        stage: String,
        iter: usize,
        checkpoint: PathBuf,
    },
}

impl Error {
    /// An invalid-value error for `field` (see [`DomainError::invalid`]).
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Domain(DomainError::invalid(field, message))
    }

    /// A file-level error for `field` of `file`.
    pub fn field(
        file: impl Into<PathBuf>,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Domain(DomainError::field(file, field, message))
    }

    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Domain(DomainError::io(path, source))
    }

    /// Attach a file to a domain error raised without one; others are returned unchanged.
    pub fn in_file(self, file: impl Into<PathBuf>) -> Self {
        match self {
            Error::Domain(e) => Error::Domain(e.in_file(file)),
            other => other,
        }
    }

    /// Prefix a domain error's field path (e.g. `channels[1]` + `kev`); others are unchanged.
    pub fn under(self, prefix: &str) -> Self {
        match self {
            Error::Domain(e) => Error::Domain(e.under(prefix)),
            other => other,
        }
    }
}

/// A field op or configuration error names its argument or field: a domain error, so that a
/// configuration's file and path prefixes attach to it like any other.
impl From<prism_field::FieldError> for Error {
    fn from(e: prism_field::FieldError) -> Self {
        Error::invalid(e.field, e.message)
    }
}
