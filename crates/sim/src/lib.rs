//! Multi-platform LiDAR simulator for perspective-invariant 3D detection (Pi3DET §3.3).
//!
//! It makes vehicle, drone and quadruped sequences with the paper's three cross-platform
//! discrepancies (ego-motion jitter, point elevation, target relative pitch), deterministic by
//! seed, and writes them in the Pi3DET layout through `pi3det-data`.
//!
//! - [`sensor`]: beam layout and return model (OS1-64, nuScenes-32, HDL-64 presets).
//! - [`scene`], [`roads`], [`terrain`]: procedural urban / suburban / park layouts.
//! - [`actors`]: vehicles and pedestrians, parked and moving.
//! - [`platform`]: vehicle / drone / quadruped motion and attitude.
//! - [`raycast`]: the 2D-grid ray caster; [`sequence`]: one sequence rendered frame by frame.
//! - [`export`]: datasets in the Pi3DET layout (train/val split by sequence), [`stats`]: the
//!   discrepancy statistics, [`preview`]: bird's-eye PNG, [`bench`]: throughput.

pub mod actors;
pub mod bench;
#[cfg(feature = "cli")]
pub mod cli;
pub mod config;
mod error;
pub mod export;
pub mod platform;
pub mod preview;
pub mod raycast;
pub mod rng;
pub mod roads;
pub mod route;
pub mod scene;
pub mod sensor;
pub mod sequence;
pub mod shapes;
pub mod stats;
pub mod terrain;

pub use config::{LabelConfig, SimConfig};
pub use error::SimError;
pub use export::{export, export_split, pi3det_mini, stratified_layouts, ExportOptions, ExportReport, PlatformPlan};
pub use scene::Layout;
pub use sensor::{SensorConfig, SensorPreset};
pub use sequence::{Sequence, SequenceSpec, SimFrame};
pub use stats::{DiscrepancyStats, StatsAccumulator};
