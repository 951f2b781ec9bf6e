//! The annotation toolkit's error: every variant names the file or the option it is about.

use std::path::{Path, PathBuf};

use pi3det_data::DataError;
use pi3det_eval::EvalError;

#[derive(Debug, thiserror::Error)]
pub enum AutolabelError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error("invalid configuration: {0}")]
    Config(String),
    #[error("{0}")]
    Input(String),
}

impl AutolabelError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }

    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::Invalid { path: path.as_ref().to_path_buf(), message: message.into() }
    }
}
