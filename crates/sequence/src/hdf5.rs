//! The few HDF5 reads the release needs, on `hdf5-pure` (pure Rust, no libhdf5).
//!
//! Files are opened for streaming: only the superblock and the objects we touch are read, and
//! `/ouster/data` is read one sweep (row) at a time, so a 40 GB sequence costs one chunk of
//! memory. Every size is checked against a cap before anything is allocated for it, so a header
//! claiming a huge shape gives an error instead of an allocation.

use std::path::{Path, PathBuf};

use crate::error::{Result, SequenceError};

/// Largest read we allocate for in one go (one sweep, or a whole small dataset such as poses).
/// A 128-beam 2048-column sweep is about 3.2 MB; this leaves a wide margin.
pub const MAX_READ_BYTES: u64 = 256 << 20;

pub struct H5File {
    path: PathBuf,
    file: hdf5_pure::File,
}

impl std::fmt::Debug for H5File {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("H5File").field("path", &self.path).finish()
    }
}

/// One dataset of an open file, with its shape and element size checked once.
pub struct H5Dataset {
    path: PathBuf,
    name: String,
    ds: hdf5_pure::Dataset,
    shape: Vec<u64>,
    element_bytes: u64,
}

impl H5File {
    pub fn open(path: &Path) -> Result<Self> {
        if let Err(e) = std::fs::metadata(path) {
            return Err(SequenceError::invalid(path, format!("cannot open: {e}")));
        }
        let file = hdf5_pure::File::open_streaming(path).map_err(|e| SequenceError::hdf5(path, "file", e))?;
        Ok(Self { path: path.to_path_buf(), file })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn dataset(&self, name: &str) -> Result<H5Dataset> {
        let err = |e: hdf5_pure::Error| SequenceError::hdf5(&self.path, name, e);
        let ds = self.file.dataset(name).map_err(err)?;
        let shape = ds.shape().map_err(err)?;
        let element_bytes = ds.element_size().map_err(err)?;
        Ok(H5Dataset { path: self.path.clone(), name: name.to_string(), ds, shape, element_bytes })
    }
}

impl H5Dataset {
    pub fn shape(&self) -> &[u64] {
        &self.shape
    }

    fn err(&self, e: impl std::fmt::Display) -> SequenceError {
        SequenceError::hdf5(&self.path, &self.name, e)
    }

    /// Bytes of one row (everything after the first dimension), checked against the cap.
    pub fn row_bytes(&self) -> Result<u64> {
        let elems = self.shape.iter().skip(1).try_fold(1u64, |a, &d| a.checked_mul(d));
        let bytes = elems.and_then(|e| e.checked_mul(self.element_bytes));
        match bytes {
            Some(b) if b <= MAX_READ_BYTES => Ok(b),
            _ => Err(self.err(format!(
                "rows of shape {:?} × {} bytes exceed the {} MiB read limit (corrupt header?)",
                &self.shape[1.min(self.shape.len())..],
                self.element_bytes,
                MAX_READ_BYTES >> 20
            ))),
        }
    }

    fn check_total(&self) -> Result<()> {
        self.check_chunks()?;
        let n = self.shape.first().copied().unwrap_or(1);
        match self.row_bytes()?.checked_mul(n) {
            Some(b) if b <= MAX_READ_BYTES => Ok(()),
            _ => Err(self.err(format!(
                "shape {:?} is larger than the {} MiB read limit",
                self.shape,
                MAX_READ_BYTES >> 20
            ))),
        }
    }

    /// A chunk is decompressed whole: its claimed size is capped like a read.
    pub fn check_chunks(&self) -> Result<()> {
        let Some(chunk) = self.ds.chunk_shape().map_err(|e| self.err(e))? else { return Ok(()) };
        let bytes = chunk.iter().try_fold(self.element_bytes, |a, &d| a.checked_mul(d));
        match bytes {
            Some(b) if b <= MAX_READ_BYTES => Ok(()),
            _ => Err(self.err(format!("chunks of shape {chunk:?} exceed the {} MiB read limit", MAX_READ_BYTES >> 20))),
        }
    }

    /// The raw bytes of row `row` (e.g. one sweep's packets); call [`check_chunks`](Self::check_chunks)
    /// once before.
    pub fn read_row(&self, row: u64) -> Result<Vec<u8>> {
        let expect = self.row_bytes()?;
        let n = self.shape.first().copied().unwrap_or(0);
        if row >= n {
            return Err(self.err(format!("row {row} out of range (the data set has {n} rows)")));
        }
        let bytes = self.ds.read_raw_rows(row, 1).map_err(|e| self.err(e))?;
        if bytes.len() as u64 != expect {
            return Err(self.err(format!("row {row}: read {} bytes, expected {expect}", bytes.len())));
        }
        Ok(bytes)
    }

    pub fn read_f64(&self) -> Result<Vec<f64>> {
        self.check_total()?;
        self.ds.read_f64().map_err(|e| self.err(e))
    }

    pub fn read_i64(&self) -> Result<Vec<i64>> {
        self.check_total()?;
        self.ds.read_i64().map_err(|e| self.err(e))
    }

    /// A text value: a (scalar or one-element) string data set, or bytes (uint8 / int8).
    pub fn read_text(&self) -> Result<String> {
        self.check_total()?;
        if let Ok(strings) = self.ds.read_string() {
            return strings.into_iter().next().ok_or_else(|| self.err("empty string data set"));
        }
        let bytes = self.ds.read_raw().map_err(|e| self.err(e))?;
        let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
        String::from_utf8(bytes[..end].to_vec()).map_err(|e| self.err(format!("not UTF-8 text: {e}")))
    }
}
