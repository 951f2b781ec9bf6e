//! The sequence reader's error: every variant names the file it is about.

use std::path::{Path, PathBuf};

use pi3det_data::DataError;

#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: HDF5 {object}: {message}")]
    Hdf5 { path: PathBuf, object: String, message: String },
    #[error(transparent)]
    Data(#[from] DataError),
}

impl SequenceError {
    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::Invalid { path: path.as_ref().to_path_buf(), message: message.into() }
    }

    pub fn hdf5(path: impl AsRef<Path>, object: &str, error: impl std::fmt::Display) -> Self {
        Self::Hdf5 { path: path.as_ref().to_path_buf(), object: object.to_string(), message: error.to_string() }
    }
}

/// The `Dataset` trait speaks `DataError`; the message keeps the file and what was wrong.
impl From<SequenceError> for DataError {
    fn from(e: SequenceError) -> Self {
        match e {
            SequenceError::Data(d) => d,
            SequenceError::Invalid { path, message } => DataError::Invalid { path, message },
            SequenceError::Hdf5 { path, object, message } => {
                DataError::Invalid { path, message: format!("HDF5 {object}: {message}") }
            }
        }
    }
}

pub type Result<T, E = SequenceError> = std::result::Result<T, E>;
