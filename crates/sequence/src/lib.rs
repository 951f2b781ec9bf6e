//! The full Pi3DET sequence release (M3ED-based): per platform (`Car` = vehicle, `Falcon` = drone,
//! `Spot` = quadruped) and condition, `processed/<Platform>/<condition>/<sequence>/` with raw
//! Ouster packets in `*data*.h5`, poses in `*pose*.h5` and pseudo-labels in
//! `ps_labels/final_ps_dict.pkl`.
//!
//! - [`hdf5`]: the HDF5 reads, on the pure-Rust `hdf5-pure` (LZF chunks, one sweep at a time);
//! - [`ouster`]: the sensor metadata, packet decoding and XYZ as the Ouster SDK computes them;
//! - [`labels`]: the pseudo-label dict;
//! - [`dataset`]: a sequence folder or a tree of them as a lazy [`pi3det_data::Dataset`];
//! - [`convert`]: writing them in the released Pi3DET layout, which every pi3det command reads.

pub mod bench;
pub mod convert;
pub mod dataset;
pub mod error;
pub mod hdf5;
pub mod labels;
pub mod ouster;
pub mod synth;

pub use dataset::{find_sequences, Sequence, SequenceDataset, SequenceOptions};
pub use error::SequenceError;
pub use labels::LabelFrame;

use std::path::Path;

/// Opens `path` as a sequence release when it holds sequence folders, else through
/// [`pi3det_data::open`] (which cannot depend on this crate).
pub fn open(path: &Path, options: SequenceOptions) -> Result<Box<dyn pi3det_data::Dataset>, pi3det_data::DataError> {
    if path.is_dir() && pi3det_data::pi3det::info_files(path).map(|f| f.is_empty()).unwrap_or(true) {
        let found = find_sequences(path);
        if !found.is_empty() {
            return Ok(Box::new(SequenceDataset::open(path, options)?));
        }
    }
    pi3det_data::open(path)
}
