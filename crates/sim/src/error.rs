//! The simulator's error type.

use std::path::PathBuf;

use pi3det_data::DataError;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Config { path: PathBuf, message: String },
    #[error("invalid simulator setting: {0}")]
    Invalid(String),
    #[error("{path}: cannot render preview: {message}")]
    Preview { path: PathBuf, message: String },
}

impl SimError {
    pub fn invalid(message: impl Into<String>) -> Self {
        Self::Invalid(message.into())
    }
}
