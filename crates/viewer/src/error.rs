//! The viewer's error: every variant names the file, the option or the frame it is about.

use std::path::{Path, PathBuf};

use pi3det_data::DataError;
use pi3det_eval::EvalError;

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: already exists (pass --overwrite to replace it)")]
    Exists { path: PathBuf },
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Detections(#[from] EvalError),
    #[error("{0}")]
    Option(String),
    #[error("cannot listen on {addr}: {message}")]
    Listen { addr: String, message: String },
}

impl ViewerError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }

    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::Invalid { path: path.as_ref().to_path_buf(), message: message.into() }
    }
}
