//! One error type for the domain. Every variant names where the problem is (a file, a field, or
//! both) so a user can fix their input without reading code.

use std::path::PathBuf;

/// Result alias used throughout `prism-domain`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A value in a file (or in a configuration) is missing, malformed or out of range.
    /// `field` is a dotted path such as `geometry.detector.pitch_u`; `.` is the whole file.
    #[error("{}: {}{message}", file.display(), field_label(field))]
    Field {
        file: PathBuf,
        field: String,
        message: String,
    },
    /// A value is out of range where no file is involved (a programmatic call).
    #[error("`{field}`: {message}")]
    Invalid { field: String, message: String },
}

/// `Ok` when `v` is finite and positive, else an [`Error::Invalid`] naming `field`.
pub fn ensure_positive(field: impl AsRef<str>, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(
            field.as_ref(),
            format!("must be positive and finite (got {v})"),
        ))
    }
}

/// `Ok` when `v` is finite and ≥ 0 (a weight that may switch a term off), else an
/// [`Error::Invalid`] naming `field`.
pub fn ensure_non_negative(field: impl AsRef<str>, v: f64) -> Result<()> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(
            field.as_ref(),
            format!("must be finite and ≥ 0 (got {v})"),
        ))
    }
}

/// `Ok` when `v` is finite, else an [`Error::Invalid`] naming `field`.
pub fn ensure_finite(field: impl AsRef<str>, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(
            field.as_ref(),
            format!("must be finite (got {v})"),
        ))
    }
}

/// `Ok` when an array's shape equals `want`, else an [`Error::Invalid`] naming `field`, e.g.
/// "shape [3, 4] does not match [views, rows, cols] = [3, 5]".
pub fn ensure_shape(field: &str, got: &[usize], want: &[usize], what: &str) -> Result<()> {
    if got == want {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            format!("shape {got:?} does not match {what} = {want:?}"),
        ))
    }
}

/// `field `a.b`: ` for a field path, nothing for the whole file (`.`).
fn field_label(field: &str) -> String {
    if field == "." || field.is_empty() {
        String::new()
    } else {
        format!("field `{field}`: ")
    }
}

impl Error {
    /// An invalid-value error for `field`.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// A file-level error for `field` of `file`.
    pub fn field(
        file: impl Into<PathBuf>,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Field {
            file: file.into(),
            field: field.into(),
            message: message.into(),
        }
    }

    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    /// Attach a file to an error raised without one (e.g. a validation error found while loading
    /// a file); other variants are returned unchanged.
    pub fn in_file(self, file: impl Into<PathBuf>) -> Self {
        match self {
            Error::Invalid { field, message } => Error::Field {
                file: file.into(),
                field,
                message,
            },
            other => other,
        }
    }

    /// Prefix the field path (e.g. `geometry` + `dso` → `geometry.dso`).
    pub fn under(self, prefix: &str) -> Self {
        let join = |f: String| {
            if f.is_empty() {
                prefix.to_string()
            } else {
                format!("{prefix}.{f}")
            }
        };
        match self {
            Error::Invalid { field, message } => Error::Invalid {
                field: join(field),
                message,
            },
            Error::Field {
                file,
                field,
                message,
            } => Error::Field {
                file,
                field: join(field),
                message,
            },
            other => other,
        }
    }
}
