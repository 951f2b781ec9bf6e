//! Orchestration above the crates: drivers that need the simulator (`pi3det-sim`) and the
//! detectors (`pi3det-nn`) together, and the `pi3det-torch` binary that runs the detector
//! commands (`pi3det train / detect / demo / bench nn`; the `pi3det` binary hands them over, so
//! that it never loads libtorch itself).
//!
//! | module | what |
//! | --- | --- |
//! | [`autolabel`] | `pi3det autolabel`: checkpoints × test-time augmentation → box fusion → tracking → a new label set |
//! | [`benchmark`] | `pi3det benchmark`: the cross-platform benchmark (source-only, target-only, ST3D, ST3D++, SN, REDB, MS3D++, Pi3DET-Net) as resumable, shardable cells → the paper's tables |
//! | [`bench_live`] | `pi3det bench live`: `pi3det run` on loopback, latency with and without VPP, soak |
//! | [`bench_real`] | `pi3det bench real`: a checkpoint on every real labelled set (`../shared/data`), one table with a pooled row |
//! | [`demo`] | `pi3det demo`: simulate vehicle / drone / quadruped data, train on the vehicle, evaluate on all three; several seeds with mean ± std |
//! | [`run`] | `pi3det run`: a detector on a live or recorded stream (Ouster UDP, ROS 2 bag, dataset) into JSON lines / Foxglove MCAP, with latency percentiles |
//! | [`export`] | `pi3det export`: a checkpoint's network as TorchScript, traced on one frame |
//! | [`frames`] | simulated frames where a command needs some and was given none (`bench nn`) |
//!
pub mod autolabel;
pub mod bench_live;
pub mod bench_real;
pub mod benchmark;
pub mod demo;
pub mod export;
pub mod frames;
pub mod run;
