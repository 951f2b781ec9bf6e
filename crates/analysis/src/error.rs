//! The analysis crate's error.

use std::path::{Path, PathBuf};

use pi3det_data::DataError;

#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: JSON: {source}")]
    Json { path: PathBuf, source: serde_json::Error },
    #[error("plot {path}: {message}")]
    Plot { path: PathBuf, message: String },
    #[error("invalid input: {0}")]
    Invalid(String),
}

impl AnalysisError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }

    pub fn plot(path: &Path, message: impl ToString) -> Self {
        Self::Plot { path: path.to_path_buf(), message: message.to_string() }
    }
}
