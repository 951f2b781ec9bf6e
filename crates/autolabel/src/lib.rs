//! The annotation toolkit of Pi3DET (paper appendix A.6), without libtorch: several detectors'
//! boxes fused by kernel density estimation as MS3D++ does ([`fusion`]), tracked in the world
//! frame for temporal consistency and interpolation ([`tracking`]), and checked against the
//! cameras ([`project`]). `pi3det autolabel` (crates/pipelines) runs the detectors in front.

pub mod error;
pub mod project;

#[cfg(feature = "cli")]
pub mod cli;

pub use error::AutolabelError;
