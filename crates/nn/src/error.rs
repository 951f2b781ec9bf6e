//! The neural-network crate's error.

use std::path::{Path, PathBuf};

use pi3det_data::DataError;

#[derive(Debug, thiserror::Error)]
pub enum NnError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
    #[error("{path}: invalid config: {message}")]
    ConfigFile { path: PathBuf, message: String },
    #[error("invalid config: {0}")]
    Config(String),
    #[error("{path}: not a pi3det checkpoint: {message}")]
    Checkpoint { path: PathBuf, message: String },
    #[error("device: {0}")]
    Device(String),
    #[error("{0}")]
    Input(String),
    #[error("training diverged: {0}")]
    Diverged(String),
    #[error("evaluation: {0}")]
    Eval(String),
    #[error("data loader thread stopped: {0}")]
    Loader(String),
}

impl NnError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }
}

pub type Result<T, E = NnError> = std::result::Result<T, E>;
