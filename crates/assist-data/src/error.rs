//! Errors of dataset reading and writing. Every variant names the file, and where it is
//! about a value, the field (a JSON path like `frames[3].transform_matrix`) and what was
//! expected.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}", path = path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The file is not valid JSON.
    #[error("{path}: not valid JSON at line {line}, column {column}: {message}", path = path.display())]
    Json {
        path: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
    /// A value in the file is missing, of the wrong type, or out of range.
    #[error("{path}: {field}: {message}", path = path.display())]
    Field {
        path: PathBuf,
        field: String,
        message: String,
    },
    /// An image (or mask, or depth map) could not be decoded.
    #[error("{path}: cannot decode image: {message}", path = path.display())]
    Image { path: PathBuf, message: String },
    /// An image decoded at a size other than the one the dataset declares.
    #[error("{path}: image is {got_w}x{got_h}, expected {want_w}x{want_h} ({field})", path = path.display())]
    ImageSize {
        path: PathBuf,
        field: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    /// A binary file ends before a record is complete.
    #[error("{path}: truncated: {message}", path = path.display())]
    Truncated { path: PathBuf, message: String },
    /// Nothing at the path looks like a dataset assist can read.
    #[error("{path}: {message}", path = path.display())]
    NotADataset { path: PathBuf, message: String },
    /// Writing would replace something the user has.
    #[error("{path}: already exists; pass --force to overwrite", path = path.display())]
    Exists { path: PathBuf },
    /// An output folder that may not be written (not assist's, in use, no space).
    #[error(transparent)]
    Output(#[from] assist_fs::FsError),
}

pub type Result<T, E = DataError> = std::result::Result<T, E>;

impl DataError {
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
    pub fn field(
        path: impl AsRef<Path>,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        DataError::Field {
            path: path.as_ref().to_path_buf(),
            field: field.into(),
            message: message.into(),
        }
    }
    /// Converts a core validation error about `path`.
    pub fn core(path: impl AsRef<Path>, e: assist_core::CoreError) -> Self {
        match e {
            assist_core::CoreError::NotFinite { field, value } => DataError::field(
                path,
                field,
                format!("expected a finite number, got {value}"),
            ),
            assist_core::CoreError::Invalid { field, message } => {
                DataError::field(path, field, message)
            }
        }
    }
}
