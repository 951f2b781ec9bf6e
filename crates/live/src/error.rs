use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// A source or sink address that cannot be used, with what is wrong.
    #[error("{uri}: {message}")]
    Uri { uri: String, message: String },
    /// Input whose content is wrong, naming the file (or address) and the problem.
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    #[error(transparent)]
    Data(#[from] pi3det_data::DataError),
    #[error(transparent)]
    Sequence(#[from] pi3det_sequence::SequenceError),
}

impl LiveError {
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Self::Io { path: path.as_ref().to_path_buf(), source }
    }

    pub fn uri(uri: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Uri { uri: uri.into(), message: message.into() }
    }

    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::Invalid { path: path.as_ref().to_path_buf(), message: message.into() }
    }
}

pub type Result<T, E = LiveError> = std::result::Result<T, E>;
