//! `pi3det train`, `pi3det detect`, `pi3det adapt` and `pi3det bench nn`: argument structs (clap) and runners, one
//! file per command, for a binary to mount as subcommands (`pi3det-torch`, in
//! `crates/pipelines`, which `pi3det` hands these commands to). The demo, which needs the
//! simulator as well, lives in `pi3det-pipelines`.
//!
//! | module | what |
//! | --- | --- |
//! | [`args`] | shared arguments: device and libtorch threads, a dataset and the part of it to use |
//! | [`train`](mod@train) | `train`: [`TrainArgs`], [`run_train`], the progress bar ([`train_with_progress`]) |
//! | [`adapt`](mod@adapt) | `adapt`: [`AdaptArgs`], [`run_adapt`] (Pi3DET-Net, progress bars per stage) |
//! | [`detect`](mod@detect) | `detect`: [`DetectArgs`], [`run_detect`] |
//! | [`bench`](mod@bench) | `bench nn`: [`BenchNnArgs`], [`run_bench_nn`] (frames from the caller by default) |
//! | [`bench_sparse`] | `bench sparse`: the sparse 3-D backbone against dense `conv3d` |

use std::path::Path;

use indicatif::ProgressStyle;

use crate::error::{NnError, Result};

pub mod adapt;
pub mod args;
pub mod bench;
pub mod bench_sparse;
pub mod detect;
pub mod train;

pub use adapt::{adapt_with_progress, run_adapt, AdaptArgs};
pub use args::{open_subset, rewrite_old_switches, DataArgs, DeviceArgs};
pub use bench::{run_bench_nn, BenchNnArgs};
pub use bench_sparse::{run_bench_sparse, BenchSparseArgs};
pub use detect::{format_latency, run_detect, DetectArgs};
pub use train::{run_train, train_with_progress, TrainArgs};

/// The CPU preset, built in (the same text as `configs/pointpillars_cpu.toml`).
pub const CPU_PRESET: &str = include_str!("../../../../configs/pointpillars_cpu.toml");

/// The CPU preset with the second stage (`configs/pointpillars_rcnn_cpu.toml`): the demo's detector.
pub const RCNN_CPU_PRESET: &str = include_str!("../../../../configs/pointpillars_rcnn_cpu.toml");

/// Pi3DET-Net's CPU preset (`configs/pi3det_net_cpu.toml`): the demo's adaptation.
pub const PI3DET_NET_CPU_PRESET: &str = include_str!("../../../../configs/pi3det_net_cpu.toml");

/// A progress-bar style from an indicatif template (the default style if the template is bad).
pub fn progress_style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar())
}

/// Errors when `dir` already holds a file an earlier run wrote (`is_output` on its name); a
/// missing `dir` holds none.
pub fn refuse_existing(dir: &Path, is_output: impl Fn(&str) -> bool) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    match entries.flatten().map(|e| e.path()).find(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(&is_output)) {
        Some(p) => Err(NnError::Input(format!(
            "{} already exists (an earlier run's output); pass --overwrite to replace it",
            p.display()
        ))),
        None => Ok(()),
    }
}
