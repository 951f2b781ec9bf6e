//! Pi3DET-Net (Liang et al., "Perspective-Invariant 3D Object Detection", §4) and the
//! cross-domain adaptation baselines of its benchmark: adapting a detector trained on a vehicle
//! to a drone or a quadruped without target labels.
//!
//! The components that live in the detector itself are in `pi3det-nn`, each under its paper name;
//! this crate holds the stages that train with them.
//!
//! | paper | where | where it acts |
//! | --- | --- | --- |
//! | Random Platform Jitter (RPJ) | [`pi3det_nn::augment::random_platform_jitter`] | source frames, PA and KA |
//! | Virtual Platform Pose (VPP) | [`pi3det_nn::preprocess::vpp`] | target frames (a per-frame `detector_from_lidar`) |
//! | Geometry-aware Transformation Descriptor (GTD) | [`pi3det_nn::necks::gtd`] | the BEV neck; `L_rot` on source |
//! | KL Probabilistic Feature Alignment (PFA) | [`pi3det_nn::roi_heads::pfa`] | RoI features; `L_RoI` on source, `L_KL` source ↔ target |
//! | Pre-Adaptation (PA) | [`pi3det_nn::train`] with the Pi3DET-Net detector config | source |
//! | pseudo-labels | [`pseudo_labels`] | target training frames, through VPP |
//! | Knowledge-Adaptation (KA) | [`ka`] | one source and one target batch per step |
//! | KA's target background rules | [`pi3det_nn::losses::target_negatives`] | target batches' classification losses |
//! | thresholds that follow the target | [`thresholds`] | pseudo-labels' positives |
//! | the guard: positives per frame, adapted vs PA through VPP | [`guard`] | the report |
//! | the stages in order (`pi3det adapt`) | [`pipeline`] | PA → pseudo-labels → KA → guard |
//! | ST3D, ST3D++, SN, REDB, MS3D++ | [`baselines`] | the benchmark's other methods |
//!
//! `pi3det adapt --config configs/pi3det_net_cpu.toml --source DATA/vehicle/train --target
//! DATA/drone/train --val DATA/drone/val --out runs/v2d` runs the stages ([`pipeline`]).

pub mod baselines;
pub mod guard;
pub mod ka;
pub mod pipeline;
pub mod pseudo_labels;
pub mod thresholds;

pub use pipeline::{AdaptConfig, AdaptOptions, AdaptReport};
