//! Orchestration above the crates: drivers that need the simulator (`pi3det-sim`) and the
//! detectors (`pi3det-nn`) together, and the `pi3det-torch` binary that runs the detector
//! commands (`pi3det train / detect / demo / bench nn`; the `pi3det` binary hands them over, so
//! that it never loads libtorch itself).
//!
//! | module | what |
//! | --- | --- |
//! | [`autolabel`] | `pi3det autolabel`: checkpoints × test-time augmentation → box fusion → tracking → a new label set |
//! | [`demo`] | `pi3det demo`: simulate vehicle / drone / quadruped data, train on the vehicle, evaluate on all three; several seeds with mean ± std |
//! | [`frames`] | simulated frames where a command needs some and was given none (`bench nn`) |
//!
//! Later adaptation and benchmark drivers belong here too.

pub mod autolabel;
pub mod demo;
pub mod frames;
