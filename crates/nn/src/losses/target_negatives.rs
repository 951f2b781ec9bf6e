//! What a target batch's background teaches in Knowledge-Adaptation (issue 47). Pseudo-labels
//! mark the objects the labeller was sure of; everything else is background, so a target where
//! the labeller was sure of almost nothing turns into "no objects anywhere", and KA then trains
//! the detector to find nothing on the target. Two rules keep the background honest:
//!
//! - **unsure outputs are ignored**: a background anchor (or sampled RoI) that the model, as it
//!   is at this step, scores at least `unsure_score`, and that no positive pseudo-label
//!   overlaps, leaves the classification loss. It is ST3D's ignored band applied to the
//!   network's own outputs: a box the model half-believes in is no evidence of background, and
//!   the focal loss would push exactly those outputs down hardest. Outputs around a positive
//!   stay background, so localisation keeps its hard negatives.
//! - **background weighted by coverage**: a frame's background losses are scaled by
//!   `min(1, coverage / full_coverage)`, where `coverage = positives / (positives + ignored
//!   boxes)`: the share of what the labeller saw (score ≥ the band's floor) that the positives
//!   explain. A frame whose detections all fell in the ignored band (no positives) adds no
//!   background loss at all; a frame where the labeller saw nothing keeps its full background,
//!   and a frame with plenty of positives is trained as before.
//!
//! Both are near no-ops when pseudo-labels are plentiful: the band's boxes were already ignored
//! where they lie, and frames whose positives make up at least `full_coverage` of the labeller's
//! boxes keep their weight. The anchor head and the RoI head apply them
//! ([`crate::dense_heads::DenseHead::loss_target`], [`crate::roi_heads::SecondStage::loss_target`]);
//! a head without them (the center head) trains the target as before.

use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::data_loader::FrameGt;
use crate::error::{NnError, Result};

/// `[target_negatives]` of an adaptation config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TargetNegativesConfig {
    /// Off: every target output without a pseudo-label is background at full weight (before
    /// issue 47).
    pub enabled: bool,
    /// Background outputs scoring at least this (and not overlapping a positive) are ignored;
    /// absent: the pseudo-labels' `ignore_score`, the floor of the ignored band.
    pub unsure_score: Option<f64>,
    /// A frame's background weight reaches 1 when its positives are this share of its
    /// pseudo-labels (positives and ignored boxes).
    pub full_coverage: f64,
    /// The dense head's background outputs that are not next to a positive learn the
    /// pre-adapted model's own scores on the same batch instead of 0 (soft targets): what the
    /// labeller half-believed stays half-believed, so objects it saw too faintly for a
    /// pseudo-label are not trained away. Costs one extra eval-mode pass of the pre-adapted
    /// model per target batch.
    pub teacher_scores: bool,
}

impl Default for TargetNegativesConfig {
    fn default() -> Self {
        Self { enabled: true, unsure_score: None, full_coverage: 0.25, teacher_scores: false }
    }
}

impl TargetNegativesConfig {
    pub fn validate(&self) -> Result<()> {
        let unsure_ok = self.unsure_score.is_none_or(|s| (0.0..1.0).contains(&s));
        if self.teacher_scores && !self.enabled {
            return Err(NnError::config(
                "target_negatives.teacher_scores",
                "target_negatives.teacher_scores needs target_negatives.enabled = true",
            ));
        }
        if unsure_ok && self.full_coverage.is_finite() && self.full_coverage > 0.0 && self.full_coverage <= 1.0 {
            Ok(())
        } else {
            Err(NnError::config(
                "target_negatives",
                format!("target_negatives: need 0 ≤ unsure_score < 1 and 0 < full_coverage ≤ 1 (got {self:?})"),
            ))
        }
    }

    /// The rules for one target batch, from its frames' positives and ignored boxes;
    /// `ignore_score`: the band's floor (the default unsure score).
    pub fn for_batch(&self, ignore_score: f64, gt: &[FrameGt]) -> TargetNegatives {
        TargetNegatives {
            unsure_score: self.unsure_score.unwrap_or(ignore_score),
            frame_weight: gt
                .iter()
                .map(|g| negative_weight(g.boxes.len(), g.ignored.len(), self.full_coverage))
                .collect(),
        }
    }
}

/// The share of a frame's pseudo-labels that are positives; 1 for a frame without any (the
/// labeller saw nothing there, so its background is what the labeller believed).
pub fn coverage(positives: usize, ignored: usize) -> f64 {
    if positives + ignored == 0 {
        1.0
    } else {
        positives as f64 / (positives + ignored) as f64
    }
}

/// The weight of a frame's background losses: `min(1, coverage / full_coverage)`.
pub fn negative_weight(positives: usize, ignored: usize, full_coverage: f64) -> f64 {
    (coverage(positives, ignored) / full_coverage).min(1.0)
}

/// The rules as one target batch's loss applies them.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetNegatives {
    pub unsure_score: f64,
    /// Per frame of the batch: the weight of its background losses.
    pub frame_weight: Vec<f64>,
}

impl TargetNegatives {
    /// `[B]` f32 frame weights on `device`.
    pub fn weights(&self, device: Device) -> Tensor {
        let w: Vec<f32> = self.frame_weight.iter().map(|&w| w as f32).collect();
        Tensor::from_slice(&w).to_device(device)
    }

    /// The mean frame weight (1 for an empty batch).
    pub fn mean_weight(&self) -> f64 {
        if self.frame_weight.is_empty() {
            1.0
        } else {
            self.frame_weight.iter().sum::<f64>() / self.frame_weight.len() as f64
        }
    }

    /// Per output `[B, N]` (`scores`: the model's detached scores in [0, 1]): the background
    /// outputs (`background`, bool) that are unsure and not near a positive (`near`, bool or
    /// `None`: none is).
    pub fn unsure(&self, scores: &Tensor, background: &Tensor, near: Option<&Tensor>) -> Tensor {
        let m = scores.ge(self.unsure_score).logical_and(background);
        match near {
            Some(n) => m.logical_and(&n.logical_not()),
            None => m,
        }
    }

    /// `[B, N]` f32 weights of outputs: `frame_weight[b]` where `background` (bool), else 1.
    pub fn background_weights(&self, background: &Tensor) -> Tensor {
        let w = self.weights(background.device()).to_kind(Kind::Float).unsqueeze(1);
        let bg = background.to_kind(Kind::Float);
        (1.0 - &bg) + bg * w
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::Box3d;

    #[test]
    fn coverage_and_weights_by_hand() {
        assert_eq!(coverage(0, 0), 1.0);
        assert_eq!(coverage(0, 5), 0.0);
        assert_eq!(coverage(3, 1), 0.75);
        assert_eq!(negative_weight(0, 7, 0.5), 0.0, "only ignored boxes: no background loss");
        assert_eq!(negative_weight(1, 3, 0.5), 0.5);
        assert_eq!(negative_weight(2, 2, 0.5), 1.0);
        assert_eq!(negative_weight(0, 0, 0.5), 1.0, "nothing seen: background as before");
        let b = Box3d::new(0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0);
        let gt = |p: usize, i: usize| FrameGt {
            boxes: vec![b; p],
            classes: vec![0; p],
            ignored: vec![b; i],
            ignored_classes: vec![0; i],
            platform_jitter: None,
        };
        let cfg = TargetNegativesConfig::default();
        let n = cfg.for_batch(0.2, &[gt(0, 4), gt(3, 1), gt(0, 0)]);
        assert_eq!(n.unsure_score, 0.2);
        assert_eq!(n.frame_weight, vec![0.0, 1.0, 1.0]);
        assert!((n.mean_weight() - 2.0 / 3.0).abs() < 1e-12);
        let own = TargetNegativesConfig { unsure_score: Some(0.1), ..cfg };
        assert_eq!(own.for_batch(0.2, &[]).unsure_score, 0.1);
        assert!(TargetNegativesConfig { full_coverage: 0.0, ..Default::default() }.validate().is_err());
        assert!(TargetNegativesConfig { unsure_score: Some(1.0), ..Default::default() }.validate().is_err());
    }

    #[test]
    fn unsure_outputs_and_background_weights() {
        let n = TargetNegatives { unsure_score: 0.3, frame_weight: vec![0.25, 1.0] };
        let scores = Tensor::from_slice(&[0.1f32, 0.5, 0.9, 0.4, 0.2, 0.6]).view([2, 3]);
        let bg = Tensor::from_slice(&[true, true, false, true, true, true]).view([2, 3]);
        let near = Tensor::from_slice(&[false, false, false, true, false, false]).view([2, 3]);
        let u: Vec<bool> = Vec::try_from(n.unsure(&scores, &bg, Some(&near)).view([-1])).unwrap();
        // A positive (0.9) is never unsure background; a near-positive one (0.4) stays background.
        assert_eq!(u, vec![false, true, false, false, false, true]);
        let w: Vec<f32> = Vec::try_from(n.background_weights(&bg).view([-1])).unwrap();
        assert_eq!(w, vec![0.25, 0.25, 1.0, 1.0, 1.0, 1.0]);
    }
}
