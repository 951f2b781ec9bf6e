//! Cross-domain adaptation baselines of the Pi3DET benchmark (paper Tables 2–4): the mechanisms
//! each method adds to the same detector and training loop. The benchmark runner
//! (`pi3det bench suite`, crates/cli-torch) composes them into methods.
//!
//! | method | mechanisms | where |
//! | --- | --- | --- |
//! | ST3D (Yang et al. 2021) | Random Object Scaling, triplet memory, curriculum augmentation | [`pi3det_nn::augment::random_object_scaling`], [`memory`], [`curriculum`] |
//! | ST3D++ (Yang et al. 2022) | per-class memory, hybrid score, source-assisted steps, DSNorm | [`memory`], [`hybrid_score`], [`self_training`], [`ds_norm`] |
//! | SN (Wang et al. 2020) | source sizes shifted to the target's statistics | [`pi3det_nn::augment::statistical_normalization`] |
//! | REDB (Chen et al. 2023) | reliable, diverse, class-balanced pseudo-label selection | [`redb`] |
//! | MS3D++ (Tsai et al. 2023) | detector ensemble → box fusion → tracking → fixed labels | crates/autolabel, [`self_training`] |

pub mod curriculum;
pub mod ds_norm;
pub mod hybrid_score;
pub mod memory;
pub mod redb;
pub mod self_training;

pub use curriculum::CurriculumConfig;
pub use ds_norm::DomainNorms;
pub use hybrid_score::HybridWeights;
pub use memory::{MemoryBox, MemoryConfig};
