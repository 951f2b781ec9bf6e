//! Trainable LiDAR 3D detectors on libtorch (via `tch` 0.24, libtorch 2.11 from PyPI's torch
//! wheel, installed by `scripts/setup-torch`): PointPillars with the SECOND-style anchor head or
//! the CenterPoint center head, as OpenPCDet builds them; Rust pillarization, augmentation
//! (including Pi3DET's Random Platform Jitter) and target assignment on a prefetching loader
//! thread; training with AdamW and a one-cycle schedule; safetensors checkpoints; inference
//! writing the formats `pi3det-eval` reads.
//!
//! | module | what |
//! | --- | --- |
//! | [`pillarize`] | points → pillars (or voxels) with decorated point features (rayon) |
//! | [`vfe`] | the `vfe` slot: pillar feature net, mean voxel features |
//! | [`backbones_3d`], [`sparse`] | the `backbone_3d` slot (`VoxelBackBone8x`); sparse 3-D convolution (rulebooks in Rust, gather → GEMM → scatter-add in tch) |
//! | [`map_to_bev`] | the `map_to_bev` slot: pillar scatter, height compression |
//! | [`backbone_2d`], [`necks`] | the BEV backbone; the BEV-to-BEV slot (GTD) |
//! | [`dense_heads`] | anchor head, center head |
//! | [`roi_heads`] | the second stage: proposals, RoI sampling, BEV / point / voxel RoI pooling, IoU-guided score and box refinement; PFA on the RoI features |
//! | [`target_assigner`], [`box_coder`], [`losses`] | anchors and IoU assignment, Gaussian heatmaps, encodings, losses (with KA's target background rules) |
//! | [`augment`] | world flip / rotation / scaling, random object rotation / scaling, GT sampling, Random Platform Jitter, sensor randomisation |
//! | [`detector`] | the model chain `vfe → [backbone_3d] → map_to_bev → backbone_2d → [neck] → dense_head → [roi_head]` |
//! | [`preprocess`] | per-frame `detector_from_lidar` (levelling, VPP), pillars and targets |
//! | [`post_process`] | score threshold and rotated NMS, then the box fits, the upright check, test-time augmentation |
//! | [`data_loader`], [`train`], [`optim`], [`checkpoint`] | batches on a background thread, the training loop, AdamW + one-cycle, safetensors checkpoints |
//! | [`detect`], [`eval`], [`export`] | inference over a dataset, JSON lines / `result.pkl`, evaluation with `pi3det-eval`; TorchScript |
//! | [`config`], [`config_override`], [`device`], [`precision`] | the TOML config and `--set`; CPU / CUDA, threads; f32 / bf16 |
//!
//! Pi3DET-Net's stages and the adaptation baselines are in `pi3det-adapt`; the commands that run
//! all of this (`pi3det train / detect / adapt / bench nn …`) are in `pi3det-cli-torch`.
//!
//! Devices: [`device`] picks CUDA when libtorch's CUDA library loads and finds a GPU
//! (`--device auto`), else the CPU; on the CPU the BEV network runs channels-last (oneDNN) and
//! libtorch uses every core unless told otherwise ([`device::default_threads`]).

pub mod augment;
pub mod backbone_2d;
pub mod backbones_3d;
pub mod box_coder;
pub mod checkpoint;
pub mod config;
pub mod config_override;
pub mod data_loader;
pub mod dense_heads;
pub mod detect;
pub mod detector;
pub mod device;
pub mod error;
pub mod eval;
pub mod export;
pub mod losses;
pub mod map_to_bev;
pub mod necks;
pub mod optim;
pub mod pillarize;
pub mod post_process;
pub mod precision;
pub mod preprocess;
pub mod roi_heads;
pub mod sparse;
pub mod target_assigner;
pub mod testing;
pub mod train;
pub mod vfe;

pub use config::DetectorConfig;
pub use detector::{Detection, Detector};
pub use error::{NnError, Result};

// `BatchNorm` is defined below.

/// Batch-norm settings shared by every layer (OpenPCDet: eps 1e-3, momentum 0.01).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BatchNorm {
    pub eps: f64,
    /// Weight of the current batch in the running statistics.
    pub momentum: f64,
}

impl Default for BatchNorm {
    fn default() -> Self {
        Self { eps: 1e-3, momentum: 0.01 }
    }
}

impl BatchNorm {
    pub fn config(&self) -> tch::nn::BatchNormConfig {
        tch::nn::BatchNormConfig { eps: self.eps, momentum: self.momentum, ..Default::default() }
    }
}
