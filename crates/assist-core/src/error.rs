//! Errors of the core types: all of them are about values that do not make sense.

/// A value given to a core constructor that cannot describe a camera or transform.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CoreError {
    /// A number that must be finite was NaN or infinite.
    #[error("{field}: expected a finite number, got {value}")]
    NotFinite { field: String, value: f64 },
    /// A value outside the range it must lie in.
    #[error("{field}: {message}")]
    Invalid { field: String, message: String },
}

impl CoreError {
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        CoreError::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }
}

/// Checks that every value is finite, naming the first one that is not.
pub fn check_finite(field: &str, values: &[f64]) -> Result<(), CoreError> {
    for (i, &v) in values.iter().enumerate() {
        if !v.is_finite() {
            let field = if values.len() > 1 {
                format!("{field}[{i}]")
            } else {
                field.to_string()
            };
            return Err(CoreError::NotFinite { field, value: v });
        }
    }
    Ok(())
}
