//! A numpy-aware Python pickle reader and writer in pure Rust.
//!
//! Reads the pickles the 3D detection tool chains write — Pi3DET / OpenPCDet info and result
//! files, mmdet3d info files — with protocols 0–5, decoding numpy arrays, dtypes and scalars
//! into [`Value`] / [`NdArray`]; writes protocol-4 pickles that `pickle.load` (numpy 1.x or 2.x)
//! turns back into the same numpy arrays.
//!
//! ```
//! use pi3det_data::pickle::{self, NdArray, Value};
//!
//! let boxes = NdArray::new(vec![1, 7], vec![1.0f32, 2.0, 0.5, 4.0, 1.8, 1.6, 0.1]).unwrap();
//! let info = Value::dict([("frame_id", Value::from("0000001")), ("boxes", boxes.into())]);
//! let bytes = pickle::to_vec(&info).unwrap();
//! let back = pickle::from_slice(&bytes).unwrap();
//! assert_eq!(back.get("frame_id").and_then(Value::as_str), Some("0000001"));
//! let boxes = back.get("boxes").and_then(Value::as_array).unwrap();
//! assert_eq!(boxes.shape(), &[1, 7]);
//! assert_eq!(boxes.to_f64_rows().unwrap()[0][3], 4.0);
//! ```
//!
//! Not supported (clear errors): out-of-band buffers (NEXT_BUFFER), persistent ids, the
//! extension registry, structured / datetime / complex dtypes, recursive values, integers
//! beyond `i64`. Instances of dict and list subclasses (OrderedDict, defaultdict, EasyDict...)
//! decode as plain `Dict` / `List`; other classes become [`Value::Object`].

mod de;
mod error;
mod numpy;
mod objects;
mod opcodes;
mod reduce;
mod ser;
mod text;
mod value;

use std::io::Write;
use std::path::Path;

pub use error::PickleError;
pub use value::{ArrayData, NdArray, Value};

/// Decodes a pickle held in memory.
pub fn from_slice(bytes: &[u8]) -> Result<Value, PickleError> {
    de::unpickle(bytes)
}

/// Reads and decodes a pickle file; errors name the path.
pub fn from_path(path: impl AsRef<Path>) -> Result<Value, PickleError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|error| PickleError::Io { path: path.to_owned(), error })?;
    from_slice(&bytes).map_err(|error| PickleError::InFile { path: path.to_owned(), error: Box::new(error) })
}

/// Encodes a value as a protocol-4 pickle.
pub fn to_vec(value: &Value) -> Result<Vec<u8>, PickleError> {
    ser::pickle(value)
}

/// Writes a pickle file atomically: the bytes go to a temporary file in the same directory,
/// which is then moved into place, so readers never see a partial file. An existing file is
/// only replaced when `overwrite` is true.
pub fn to_path(path: impl AsRef<Path>, value: &Value, overwrite: bool) -> Result<(), PickleError> {
    let path = path.as_ref();
    let bytes = to_vec(value)?;
    let io_err = |error| PickleError::Io { path: path.to_owned(), error };
    if !overwrite && path.exists() {
        return Err(PickleError::AlreadyExists { path: path.to_owned() });
    }
    let name = path
        .file_name()
        .ok_or_else(|| io_err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file path")))?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let tmp = temp_file_path(dir, name);
    let result = write_new(&tmp, &bytes).and_then(|()| {
        if overwrite {
            std::fs::rename(&tmp, path)
        } else {
            // A hard link fails if the destination appeared meanwhile, unlike rename.
            std::fs::hard_link(&tmp, path).or_else(|e| match e.kind() {
                std::io::ErrorKind::AlreadyExists => Err(e),
                // Filesystems without hard links: check, then rename.
                _ if path.exists() => Err(std::io::ErrorKind::AlreadyExists.into()),
                _ => std::fs::rename(&tmp, path),
            })
        }
    });
    // After a rename the temporary name is gone; after a hard link it must go.
    let _ = std::fs::remove_file(&tmp);
    match result {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            Err(PickleError::AlreadyExists { path: path.to_owned() })
        }
        Err(e) => Err(io_err(e)),
    }
}

fn temp_file_path(dir: &Path, name: &std::ffi::OsStr) -> std::path::PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp{}-{n}", std::process::id()));
    dir.join(tmp_name)
}

fn write_new(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut file = std::fs::OpenOptions::new().write(true).create_new(true).open(path)?;
    file.write_all(bytes)?;
    file.sync_all()
}

#[cfg(test)]
mod tests;
