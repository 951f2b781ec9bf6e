//! Trainable LiDAR 3D detectors on libtorch (via `tch` 0.24, libtorch 2.11 from PyPI's torch
//! wheel, installed by `scripts/setup-torch`): PointPillars with the SECOND-style anchor head or
//! the CenterPoint center head, as OpenPCDet builds them; Rust pillarization, augmentation
//! (including Pi3DET's Random Platform Jitter) and target assignment on a prefetching loader
//! thread; training with AdamW and a one-cycle schedule; safetensors checkpoints; inference
//! writing the formats `pi3det-eval` reads.
//!
//! | module | what |
//! | --- | --- |
//! | [`pillarize`] | points → pillars with decorated point features (rayon) |
//! | [`vfe`], [`scatter`], [`backbone_2d`] | pillar feature net, BEV scatter, BEV backbone |
//! | [`backbones_3d`] | the `backbone_3d` slot (`VoxelBackBone8x`) and its `map_to_bev` (height compression) |
//! | [`sparse`] | sparse 3-D convolution (rulebooks in Rust, gather → GEMM → scatter-add in tch) |
//! | [`dense_heads`] | anchor head, center head |
//! | [`target_assigner`], [`box_coder`], [`losses`] | anchors and IoU assignment, Gaussian heatmaps, encodings, losses |
//! | [`augment`] | world flip / rotation / scaling, random object rotation, GT sampling, Random Platform Jitter |
//! | [`detector`] | the model chain `vfe → map_to_bev → backbone_2d → [neck] → dense_head` |
//! | [`preprocess`], [`post_process`] | per-frame `detector_from_lidar`, pillars and targets; score threshold and rotated NMS |
//! | [`ground_fit`], [`bev_fit`] | post-NMS box fits to the points: bottom and top; heading and BEV centre |
//! | [`necks`] | the BEV-to-BEV slot |
//! | [`roi_heads`] | the second stage: proposals, RoI sampling, BEV RoI pooling, IoU-guided score and box refinement |
//! | [`data_loader`], [`train`], [`optim`], [`checkpoint`] | batches on a background thread, the training loop, AdamW + one-cycle, safetensors checkpoints |
//! | [`detect`], [`eval`] | inference over a dataset, JSON lines / `result.pkl`, evaluation with `pi3det-eval` |
//! | [`bench`](mod@bench) | the side-by-side benchmark against PyTorch (`python/bench_pointpillars.py`) |
//! | `cli` (feature `cli`) | `pi3det train / detect / bench nn` (mounted by `pi3det-torch`, crates/pipelines) |
//!
//! Devices: [`device`] picks CUDA when libtorch's CUDA library loads and finds a GPU
//! (`--device auto`), else the CPU; on the CPU the BEV network runs channels-last (oneDNN) and
//! libtorch uses every core unless told otherwise ([`device::default_threads`]).

pub mod adapt;
pub mod augment;
pub mod backbone_2d;
pub mod backbones_3d;
pub mod baselines;
pub mod bench;
pub mod bev_fit;
pub mod box_coder;
pub mod checkpoint;
#[cfg(feature = "cli")]
pub mod cli;
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
pub mod ground_fit;
pub mod losses;
pub mod necks;
pub mod optim;
pub mod pillarize;
pub mod post_process;
pub mod precision;
pub mod preprocess;
pub mod roi_heads;
pub mod scatter;
pub mod sparse;
pub mod target_assigner;
pub mod testing;
pub mod train;
pub mod tta;
pub mod upright_check;
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
