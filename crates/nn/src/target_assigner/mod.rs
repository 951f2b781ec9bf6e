//! Training targets: anchors and their IoU-based assignment (anchor head), Gaussian heatmaps and
//! centre codes (center head).

pub mod anchor_generator;
pub mod axis_aligned;
pub mod center;

pub use anchor_generator::{AnchorClassConfig, Anchors};
pub use axis_aligned::AnchorTargets;
pub use center::{CenterMap, CenterTargetConfig, CenterTargets};
