//! Pi3DET-Net (Liang et al., "Perspective-Invariant 3D Object Detection", §4): cross-platform
//! adaptation of a detector trained on a vehicle to a drone or a quadruped without target labels.
//!
//! | paper | module | where it acts |
//! | --- | --- | --- |
//! | Random Platform Jitter (RPJ) | [`crate::augment::random_platform_jitter`] | source frames, PA and KA |
//! | Virtual Platform Pose (VPP) | [`vpp`] | target frames (a per-frame `detector_from_lidar`) |
//! | Geometry-aware Transformation Descriptor (GTD) | [`crate::necks::gtd`] | the BEV neck; `L_rot` on source |
//! | KL Probabilistic Feature Alignment (PFA) | [`pfa`] | RoI features; `L_RoI` on source, `L_KL` source ↔ target |
//! | Pre-Adaptation (PA) | [`crate::train`] with the Pi3DET-Net detector config | source |
//! | pseudo-labels | [`pseudo_labels`] | target training frames, through VPP |
//! | Knowledge-Adaptation (KA) | [`ka`] | one source and one target batch per step |
//! | KA's target background rules (issue 47) | [`coverage`] | target batches' classification losses |
//! | thresholds that follow the target | [`thresholds`] | pseudo-labels' positives |
//! | the guard: positives per frame, adapted vs PA through VPP | [`guard`] | the report |
//!
//! `pi3det adapt --config configs/pi3det_net_cpu.toml --source DATA/vehicle/train --target
//! DATA/drone/train --val DATA/drone/val --out runs/v2d` runs the stages ([`pipeline`]).

pub mod coverage;
pub mod guard;
pub mod ka;
pub mod pfa;
pub mod pipeline;
pub mod pseudo_labels;
pub mod thresholds;
pub mod vpp;

pub use pfa::{KlEstimator, Latent, Pfa, PfaConfig};
pub use vpp::{AttitudeSource, VirtualPlatformPose, VppConfig, VppCounts};
