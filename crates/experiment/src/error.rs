//! The experiment crate's error: the reconstruction's (input files and fields, training), a cell
//! that failed (named), the scheduler, and figures.

use std::path::PathBuf;

pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file, field or value, or a run that failed (see [`prism_recon::Error`]).
    #[error(transparent)]
    Recon(#[from] prism_recon::Error),
    /// One cell of the suite failed; `cell` is its directory relative to the output.
    #[error("cell `{cell}`: {source}")]
    Cell {
        cell: String,
        #[source]
        source: Box<Error>,
    },
    /// Slurm refused a submission or is not installed.
    #[error("slurm: {0}")]
    Scheduler(String),
    /// A figure could not be drawn or written.
    #[error("figure {}: {message}", path.display())]
    Figure { path: PathBuf, message: String },
}

impl From<prism_domain::Error> for Error {
    fn from(e: prism_domain::Error) -> Self {
        Error::Recon(e.into())
    }
}

impl Error {
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Recon(prism_recon::Error::invalid(field, message))
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Recon(prism_recon::Error::io(path, source))
    }

    /// A file-level error for `field` of `file`.
    pub fn field(
        file: impl Into<PathBuf>,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Recon(prism_recon::Error::field(file, field, message))
    }

    /// Attach a file to an input error raised without one.
    pub fn in_file(self, file: impl Into<PathBuf>) -> Self {
        match self {
            Error::Recon(e) => Error::Recon(e.in_file(file)),
            other => other,
        }
    }

    /// This error as the failure of `cell`.
    pub fn in_cell(self, cell: impl Into<String>) -> Self {
        Error::Cell {
            cell: cell.into(),
            source: Box::new(self),
        }
    }
}
