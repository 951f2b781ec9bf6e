//! The presets built into the binary: the same text as the files in `configs/`, so a command
//! runs without a config file and a user can start from the file.

/// The CPU preset (`configs/pointpillars_cpu.toml`).
pub const CPU_PRESET: &str = include_str!("../../../configs/pointpillars_cpu.toml");

/// The CPU preset with the second stage (`configs/pointpillars_rcnn_cpu.toml`): the demo's detector.
pub const RCNN_CPU_PRESET: &str = include_str!("../../../configs/pointpillars_rcnn_cpu.toml");

/// Pi3DET-Net's CPU preset (`configs/pi3det_net_cpu.toml`): the demo's adaptation.
pub const PI3DET_NET_CPU_PRESET: &str = include_str!("../../../configs/pi3det_net_cpu.toml");
