//! The reconstruction crate's error: the domain's errors (a file, a field), the render ops' and
//! the curve model's, and a training stage that diverged; and panics inside third-party code
//! caught as values ([`catch_panics`]).

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

/// Run `f` with panics caught and their default report silenced (Burn's record readers assert on
/// some malformed records; the GPU runtime panics when it finds no adapter). On a panic, the
/// message of the first panic raised meanwhile on any thread: a runtime's worker thread may panic
/// first and make the caller's call fail in turn, with a message that says less. `None` when that
/// panic carried no text.
pub(crate) fn catch_panics<T>(f: impl FnOnce() -> T) -> std::result::Result<T, Option<String>> {
    use std::sync::{Arc, Mutex};
    let first = Arc::new(Mutex::new(None::<String>));
    let kept = Arc::clone(&first);
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let text = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned());
        if let Ok(mut first) = kept.lock()
            && first.is_none()
        {
            *first = text;
        }
    }));
    let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    std::panic::set_hook(hook);
    out.map_err(|_| first.lock().ok().and_then(|m| m.clone()))
}

#[cfg(test)]
mod tests {
    use super::catch_panics;

    #[test]
    fn catch_panics_returns_the_value_or_the_first_panics_message() {
        assert_eq!(catch_panics(|| 7), Ok(7));
        let n = 3;
        assert_eq!(
            catch_panics(|| -> i32 { panic!("bad record {n}") }),
            Err(Some("bad record 3".into()))
        );
        assert_eq!(
            catch_panics(|| -> i32 { panic!("static text") }),
            Err(Some("static text".into()))
        );
        // A worker thread panics first; the caller fails in turn with a message that says less.
        let caught = catch_panics(|| {
            let worker = std::thread::spawn(|| -> i32 { panic!("no adapter found") });
            worker.join().expect("the worker's result")
        });
        assert_eq!(caught, Err(Some("no adapter found".into())));
    }
}
