//! The data crate's error: every variant names the file it is about.

use std::path::{Path, PathBuf};

use crate::pickle::PickleError;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}:{line}: {message}")]
    Line { path: PathBuf, line: usize, message: String },
    #[error("{}", pickle_message(path, source))]
    Pickle { path: PathBuf, source: PickleError },
    #[error("{path}: already exists (pass overwrite to replace it)")]
    Exists { path: PathBuf },
    #[error("{path}: not a dataset pi3det recognises ({hint})")]
    UnknownFormat { path: PathBuf, hint: String },
}

/// A pickle error that already names this file is not prefixed with it again.
fn pickle_message(path: &Path, source: &PickleError) -> String {
    match source {
        PickleError::InFile { path: p, .. } | PickleError::Io { path: p, .. } if p == path => source.to_string(),
        _ => format!("{}: {source}", path.display()),
    }
}

/// An error and its causes on one line, each cause only where the text so far does not already
/// hold it (errors here print their source in their own message, as `"{path}: {source}"`).
pub fn report(error: &(dyn std::error::Error + 'static)) -> String {
    let mut text = error.to_string();
    let mut cause = error.source();
    while let Some(c) = cause {
        let s = c.to_string();
        if !text.contains(&s) {
            text = format!("{text}: {s}");
        }
        cause = c.source();
    }
    text
}

impl DataError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }

    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::Invalid { path: path.as_ref().to_path_buf(), message: message.into() }
    }

    pub fn line(path: &Path, line: usize, message: impl Into<String>) -> Self {
        Self::Line { path: path.to_path_buf(), line, message: message.into() }
    }
}
