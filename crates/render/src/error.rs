//! Errors of the render crate: every bad-input error names the offending field.

/// A bad input to a render op.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct RenderError {
    /// Path of the offending field, e.g. `cameras[2].fx` or `means`.
    pub field: String,
    pub message: String,
}

impl RenderError {
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, RenderError>;
