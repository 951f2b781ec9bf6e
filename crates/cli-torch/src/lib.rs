//! The `pi3det-torch` binary's crate: every command that links libtorch, its clap arguments and
//! its driver, one file per command. `pi3det` (crates/cli) hands these commands over verbatim, so
//! that it never loads libtorch itself; `pi3det train --help` is this binary's help.
//!
//! | module | what |
//! | --- | --- |
//! | [`train`](mod@train) | `pi3det train`: a detector from a TOML config, with a progress bar |
//! | [`detect`](mod@detect) | `pi3det detect`: a trained detector over a dataset → JSON lines / `result.pkl`, latency, `--eval` |
//! | [`adapt`](mod@adapt) | `pi3det adapt`: Pi3DET-Net's stages ([`pi3det_adapt::pipeline`]) with a progress bar per stage |
//! | [`autolabel`] | `pi3det autolabel`: checkpoints × test-time augmentation → box fusion → tracking → a new label set |
//! | [`run`] | `pi3det run`: a detector on a live or recorded stream (Ouster UDP, ROS 2 bag, dataset) into JSON lines / Foxglove MCAP, with latency percentiles |
//! | [`export`] | `pi3det export`: a checkpoint's network as TorchScript, traced on one frame |
//! | [`demo`] | `pi3det demo`: simulate vehicle / drone / quadruped data, train on the vehicle, evaluate on all three; several seeds with mean ± std |
//! | [`benchmark`] | `pi3det bench suite`: the cross-platform benchmark (source-only, target-only, ST3D, ST3D++, SN, REDB, MS3D++, Pi3DET-Net) as resumable, shardable cells → the paper's tables |
//! | [`bench_real`] | `pi3det bench real`: a checkpoint on every real labelled set (`../shared/data`), one table with a pooled row |
//! | [`bench_nn`] | `pi3det bench nn`: our training step and inference against PyTorch running the same network (`python/bench_pointpillars.py`) |
//! | [`bench_sparse`] | `pi3det bench sparse`: the sparse 3-D backbone against dense `conv3d` |
//! | [`bench_live`] | `pi3det bench live`: `pi3det run` on loopback, latency with and without VPP, soak |
//! | [`args`] | arguments the commands share: device and libtorch threads, a dataset and the part of it to use, levelling |
//! | [`common`], [`presets`], [`frames`] | progress bars and output checks; the built-in presets; simulated frames where a command was given none |

pub mod adapt;
pub mod args;
pub mod autolabel;
pub mod bench_live;
pub mod bench_nn;
pub mod bench_real;
pub mod bench_sparse;
pub mod benchmark;
pub mod common;
pub mod demo;
pub mod detect;
pub mod export;
pub mod frames;
pub mod presets;
pub mod run;
pub mod train;

pub use adapt::{adapt_with_progress, run_adapt, AdaptArgs};
pub use args::{open_subset, rewrite_old_switches, DataArgs, DeviceArgs};
pub use bench_nn::{run_bench_nn, BenchNnArgs};
pub use bench_sparse::{run_bench_sparse, BenchSparseArgs};
pub use common::{progress_style, refuse_existing};
pub use detect::{format_latency, run_detect, DetectArgs};
pub use presets::{CPU_PRESET, PI3DET_NET_CPU_PRESET, RCNN_CPU_PRESET};
pub use train::{run_train, train_with_progress, TrainArgs};
