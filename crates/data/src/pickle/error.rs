//! Errors of the pickle reader and writer.

use std::path::PathBuf;

/// Everything that can go wrong while reading or writing a pickle.
///
/// Reader errors carry the byte offset in the pickle stream so that a user can inspect the
/// file with `python -m pickletools` at that position.
#[derive(Debug, thiserror::Error)]
pub enum PickleError {
    /// An opcode this reader does not implement (or an unknown byte).
    #[error("unsupported pickle opcode 0x{opcode:02x} ({name}) at byte {offset}")]
    UnsupportedOpcode { opcode: u8, name: &'static str, offset: usize },
    /// The stream ended in the middle of an opcode or before STOP.
    #[error("truncated pickle: needed {needed} bytes at byte {offset}, only {available} left")]
    Truncated { needed: usize, offset: usize, available: usize },
    /// A numpy dtype that cannot be represented by [`super::ArrayData`].
    #[error("unsupported numpy dtype '{dtype}' at byte {offset}: {reason}")]
    UnsupportedDtype { dtype: String, reason: String, offset: usize },
    /// A Python int that does not fit in `i64`.
    #[error("integer at byte {offset} does not fit in a 64-bit signed integer")]
    IntOverflow { offset: usize },
    /// Structurally invalid input (stack underflow, bad memo key, wrong argument types...).
    #[error("invalid pickle at byte {offset}: {message}")]
    Invalid { offset: usize, message: String },
    /// A value that cannot be turned into a pickle (or into an array).
    #[error("cannot pickle value: {0}")]
    Unpicklable(String),
    /// Reading or decoding a file failed; the message includes the inner error.
    #[error("{}: {error}", path.display())]
    InFile { path: PathBuf, error: Box<PickleError> },
    /// An I/O error on a file.
    #[error("{}: {error}", path.display())]
    Io { path: PathBuf, error: std::io::Error },
    /// [`super::to_path`] was asked to replace a file without `overwrite = true`.
    #[error("refusing to overwrite existing file {} (pass overwrite = true to replace it)", path.display())]
    AlreadyExists { path: PathBuf },
}

impl PickleError {
    /// Byte offset in the pickle stream the error refers to, if any.
    pub fn offset(&self) -> Option<usize> {
        match self {
            Self::UnsupportedOpcode { offset, .. }
            | Self::Truncated { offset, .. }
            | Self::UnsupportedDtype { offset, .. }
            | Self::IntOverflow { offset }
            | Self::Invalid { offset, .. } => Some(*offset),
            Self::InFile { error, .. } => error.offset(),
            _ => None,
        }
    }

    pub(crate) fn invalid(offset: usize, message: impl Into<String>) -> Self {
        Self::Invalid { offset, message: message.into() }
    }
}
