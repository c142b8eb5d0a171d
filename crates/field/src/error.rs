//! Errors of the field crate: an invalid argument, named.

/// A bad argument to an encoder or field function.
#[derive(Debug, thiserror::Error)]
#[error("{field}: {message}")]
pub struct FieldError {
    /// The argument or configuration field at fault (`points`, `hash_grid.levels`, …).
    pub field: String,
    pub message: String,
}

impl FieldError {
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        FieldError {
            field: field.into(),
            message: message.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, FieldError>;
