use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Data(#[from] assist_data::DataError),
    #[error(transparent)]
    Field(#[from] assist_field::FieldError),
    #[error(transparent)]
    Scene(#[from] assist_scene::SceneFileError),
    #[error("{path}: {message}")]
    Input { path: PathBuf, message: String },
    #[error("training diverged at iteration {iteration}: {message} (the last good checkpoint was kept{})",
        .checkpoint.as_ref().map(|p| format!(" at {}", p.display())).unwrap_or_default())]
    Diverged {
        iteration: usize,
        message: String,
        checkpoint: Option<PathBuf>,
    },
    #[error("{0}")]
    Other(String),
}

pub type Result<T> = std::result::Result<T, TrainError>;
