//! Platform-discrepancy analysis (paper §3.3, Fig. 2, appendix Tables 9–14) and pose-free sensor
//! attitude from the ground plane.
//!
//! - [`ground::estimate_ground`]: roll, pitch and height of the sensor above the ground from one
//!   scan (RANSAC + least squares with a "below and roughly level" prior), with
//!   [`ground::smoothing`] along ordered sequences. This is what Virtual Platform Pose needs on
//!   data without poses.
//! - [`analyze::analyze`]: streams datasets (bounded memory, rayon) into per-platform /
//!   per-sequence / per-class statistics: ego motion, point elevation, relative pitch of targets
//!   against distance, box sizes, points per box, point distributions.
//! - [`report`] writes markdown, CSV and JSON; [`plots`] draws PNG and SVG figures, one laid out as
//!   the paper's Fig. 2, with an embedded font.

pub mod analyze;
pub mod boxes;
#[cfg(feature = "cli")]
pub mod cli;
pub mod ego_motion;
pub mod elevation;
pub mod error;
pub mod ground;
pub mod group;
pub mod histogram;
pub mod plots;
pub mod points;
pub mod report;
pub mod sample;
pub mod targets;

pub use analyze::{analyze, frame_stats, Analysis, FrameAttitude, Input, LevelChoice, Progress, StatsConfig};
pub use error::AnalysisError;
pub use ground::smoothing::{smooth_sequence, AttitudeFilter, SmoothedAttitude, SmoothingConfig};
pub use ground::{estimate_ground, AttitudePrior, GroundConfig, GroundError, GroundEstimate};
pub use group::GroupStats;
