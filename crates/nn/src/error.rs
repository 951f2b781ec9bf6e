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
    /// A config file that does not parse, or an override (`--set`) that does not fit it.
    #[error("{path}: invalid config: {message}")]
    ConfigFile { path: PathBuf, message: String },
    /// A config file that parses but whose values are refused.
    #[error("{path}: {source}")]
    InvalidConfigFile {
        path: PathBuf,
        #[source]
        source: Box<NnError>,
    },
    /// A config's TOML that does not parse or does not fit the config's fields.
    #[error("invalid config: {0}")]
    Toml(#[from] toml::de::Error),
    /// A value the config refuses: `key` is its table or field (`post.bev_fit`, `train`,
    /// `roi_head.sampler`), `message` says what is wrong (and names the key for the reader).
    #[error("invalid config: {message}")]
    Config { key: String, message: String },
    /// Parts of a model that do not fit together (outputs of an exported network, targets of
    /// another head).
    #[error("model: {0}")]
    Model(String),
    #[error("{path}: not a pi3det checkpoint: {message}")]
    Checkpoint { path: PathBuf, message: String },
    #[error("device: {0}")]
    Device(String),
    #[error("{0}")]
    Input(String),
    #[error("training diverged: {0}")]
    Diverged(String),
    #[error("evaluation: {0}")]
    Eval(#[from] pi3det_eval::EvalError),
    #[error("data loader thread stopped: {0}")]
    Loader(String),
}

impl NnError {
    /// A refused config value under `key` (see [`NnError::Config`]).
    pub fn config(key: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Config { key: key.into(), message: message.into() }
    }

    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }
}

pub type Result<T, E = NnError> = std::result::Result<T, E>;
