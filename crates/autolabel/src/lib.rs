//! The annotation toolkit of Pi3DET (paper appendix A.6), without libtorch: several detectors'
//! boxes fused by kernel density estimation as MS3D++ does ([`fusion`]), tracked in the world
//! frame for temporal consistency and interpolation ([`tracking`]), and checked against the
//! cameras ([`project`]). `pi3det autolabel` (crates/cli-torch) runs the detectors in front.

pub mod error;
pub mod fusion;
pub mod kde;
pub mod labels;
pub mod perturb;
pub mod project;
pub mod quality;
pub mod tracking;

#[cfg(feature = "cli")]
pub mod cli;

pub use error::AutolabelError;
pub use labels::LabelSet;

/// Every frame's info, in dataset order.
pub fn read_infos(path: &std::path::Path) -> Result<Vec<pi3det_data::FrameInfo>, AutolabelError> {
    Ok(pi3det_data::open(path)?.infos()?)
}
