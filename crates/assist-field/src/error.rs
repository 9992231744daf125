//! Errors of the field engine.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum FieldError {
    #[error("field config: {field}: {message}")]
    Config { field: String, message: String },
    #[error("{path}: {source}", path = path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A weights file that cannot be used: names what is wrong and where.
    #[error("{path}: {message}", path = path.display())]
    Format { path: PathBuf, message: String },
}
