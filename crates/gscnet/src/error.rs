//! The crate's error type. It mirrors `prism_domain::Error::Invalid` (a field path and a message)
//! so callers can convert without losing which input was wrong; this crate is a leaf and cannot
//! depend on `prism-domain`.

/// Result alias used throughout `prism-gscnet`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// A bad input to a curve model, a spectral grid or a curve function.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// `field` (a dotted path such as `curve_model.width` or `tau[3]`) is out of range.
    #[error("`{field}`: {message}")]
    Invalid { field: String, message: String },
}

impl Error {
    /// An invalid-value error for `field`.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// Prefix the field path (e.g. `curve_model` + `width` → `curve_model.width`).
    pub fn under(self, prefix: &str) -> Self {
        match self {
            Error::Invalid { field, message } => Error::Invalid {
                field: if field.is_empty() {
                    prefix.to_string()
                } else if field.starts_with('[') {
                    format!("{prefix}{field}")
                } else {
                    format!("{prefix}.{field}")
                },
                message,
            },
        }
    }

    /// The field path this error names.
    pub fn field(&self) -> &str {
        match self {
            Error::Invalid { field, .. } => field,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn under_joins_field_paths() {
        let e = Error::invalid("width", "must be ≥ 1").under("curve_model");
        assert_eq!(e.field(), "curve_model.width");
        let e = Error::invalid("[2]", "not finite").under("tau");
        assert_eq!(e.field(), "tau[2]");
        assert_eq!(e.to_string(), "`tau[2]`: not finite");
    }
}
