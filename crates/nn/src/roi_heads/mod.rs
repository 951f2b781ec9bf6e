//! Second stage: a RoI head that refines the dense head's boxes from the BEV feature map (in the
//! spirit of Voxel R-CNN / CenterPoint's two-stage head, but pooling bilinear samples of the 2D
//! BEV map instead of 3D voxel features, so that it stays cheap on two CPU cores). Voxel
//! detectors can pool from the voxels instead, as Voxel R-CNN does ([`voxel_roi_pool`]).
//!
//! | module | what |
//! | --- | --- |
//! | [`proposal`] | dense-head candidates → rotated NMS → proposals (RoIs), padded per batch |
//! | [`roi_sampler`] | OpenPCDet `ProposalTargetLayer`: class-aware 3D IoU, fg / hard bg / easy bg sampling, IoU-guided score targets |
//! | [`roi_coder`] | box residuals in each RoI's own frame (encode in Rust, decode on tensors), corner loss |
//! | [`bev_roi_pool`] | bilinear RoI pooling on the BEV map: `G × G` lattice or centre + 4 face centres |
//! | [`point_roi_pool`] | raw points of each RoI in its own frame, a small PointNet and a max (z evidence the BEV map lacks) |
//! | [`voxel_roi_pool`] | Voxel R-CNN's voxel RoI pooling: `G³` grid points, voxel query on the sparse backbone's stages |
//! | [`roi_head`] | the head (point layer, shared MLP, IoU and box branches), its losses and the refinement |
//!
//! Training flow (per step, after the dense head): candidates of each frame →
//! [`ProposalConfig::select`] (train limits) → [`RoiSamplerConfig::sample`] with the frame's GT →
//! [`RoiBatchTargets::collate`] → [`RoiHead::forward_t`] on `targets.rois` → [`RoiHead::loss`].
//! Inference: [`ProposalConfig::select`] (test limits) → [`ProposalBatch::collate`] →
//! [`RoiHead::forward_t`] → [`RoiHead::refine`] (then the detector's usual NMS, if wanted).
//!
//! Every box is `[x, y, z_center, dx, dy, dz, heading]` in the detector's (shifted) frame, the
//! frame the dense head predicts in and the BEV map is laid out in (see
//! [`crate::target_assigner::center::CenterMap`]).

pub mod bev_roi_pool;
pub mod pfa;
pub mod point_roi_pool;
pub mod proposal;
pub mod roi_coder;
pub mod roi_head;
pub mod roi_sampler;
pub mod voxel_roi_pool;

pub use bev_roi_pool::{BevRoiPool, BevRoiPoolConfig, PoolLayout};
pub use point_roi_pool::{PillarPoints, PointRoiPool, PointRoiPoolConfig};
pub use proposal::{ProposalBatch, ProposalConfig, Proposals};
pub use roi_coder::{boxes_to_corners, corner_loss, RoiCoder};
pub use roi_head::{RoiHead, RoiHeadConfig, RoiLosses, RoiOutput, RoiSource, ScoreFusion, ScoreTarget};
pub use roi_sampler::{FrameSample, RoiBatchTargets, RoiCategory, RoiSamplerConfig};
pub use voxel_roi_pool::{StageGeometry, VoxelPoolStage, VoxelRoiPool, VoxelRoiPoolConfig};

use rand_chacha::ChaCha8Rng;
use tch::Tensor;

use crate::data_loader::FrameGt;
use crate::error::Result;
use crate::losses::target_negatives::TargetNegatives;
use crate::losses::LossTerms;
use crate::target_assigner::CenterMap;

/// What the detector asks of a second stage; [`RoiHead`] is the one there is. Its outputs carry
/// the pooled RoI feature vectors with the boxes they belong to ([`RoiOutput::features`],
/// [`RoiOutput::rois`]) for losses that align features across domains.
pub trait SecondStage {
    fn proposal_config(&self) -> &ProposalConfig;
    /// Width `F` of [`RoiOutput::features`].
    fn feature_channels(&self) -> i64;
    /// Training RoIs and their targets from each frame's proposals and ground truth; RoIs on a
    /// frame's ignored boxes ([`FrameGt::ignored`]) are not sampled.
    fn sample(&self, proposals: &[Proposals], gt: &[FrameGt], rng: &mut ChaCha8Rng) -> Result<RoiBatchTargets>;
    /// `bev [B, C, H, W]`, `rois [B, N, 7]` → per-RoI features, score logits and box codes.
    fn forward_t(&self, src: &RoiSource, rois: &Tensor, map: &CenterMap, train: bool) -> Result<RoiOutput>;
    /// Adds the stage's named loss terms.
    fn loss(&self, out: &RoiOutput, targets: &RoiBatchTargets, losses: &mut LossTerms) -> Result<()>;
    /// The loss of a Knowledge-Adaptation target batch under its background rules
    /// ([`crate::losses::target_negatives`]); by default the plain loss.
    fn loss_target(
        &self,
        out: &RoiOutput,
        targets: &RoiBatchTargets,
        _neg: &TargetNegatives,
        losses: &mut LossTerms,
    ) -> Result<()> {
        self.loss(out, targets, losses)
    }
    /// Refined boxes `[B, N, 7]` (detector frame) and final scores `[B, N]`.
    fn refine(&self, out: &RoiOutput, rois: &Tensor, roi_scores: &Tensor, roi_labels: &Tensor) -> (Tensor, Tensor);
}

impl SecondStage for RoiHead {
    fn proposal_config(&self) -> &ProposalConfig {
        &self.cfg.proposal
    }

    fn feature_channels(&self) -> i64 {
        self.feature_dim()
    }

    fn sample(&self, proposals: &[Proposals], gt: &[FrameGt], rng: &mut ChaCha8Rng) -> Result<RoiBatchTargets> {
        let frames = proposals
            .iter()
            .zip(gt)
            .map(|(p, g)| self.cfg.sampler.sample(p, &g.boxes, &g.classes, &g.ignored, &g.ignored_classes, rng))
            .collect::<Result<Vec<_>>>()?;
        RoiBatchTargets::collate(&frames)
    }

    fn forward_t(&self, src: &RoiSource, rois: &Tensor, map: &CenterMap, train: bool) -> Result<RoiOutput> {
        RoiHead::forward_source(self, src, rois, map, train)
    }

    fn loss(&self, out: &RoiOutput, targets: &RoiBatchTargets, losses: &mut LossTerms) -> Result<()> {
        let l = RoiHead::loss(self, out, targets)?;
        for (name, t) in l.terms() {
            losses.add(name, t.shallow_clone());
        }
        Ok(())
    }

    fn loss_target(
        &self,
        out: &RoiOutput,
        targets: &RoiBatchTargets,
        neg: &TargetNegatives,
        losses: &mut LossTerms,
    ) -> Result<()> {
        let l = RoiHead::loss_with(self, out, targets, Some(neg))?;
        for (name, t) in l.terms() {
            losses.add(name, t.shallow_clone());
        }
        Ok(())
    }

    fn refine(&self, out: &RoiOutput, rois: &Tensor, roi_scores: &Tensor, roi_labels: &Tensor) -> (Tensor, Tensor) {
        RoiHead::refine(self, out, rois, roi_scores, roi_labels)
    }
}
