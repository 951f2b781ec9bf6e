//! Rotated NMS with OpenPCDet's semantics (`class_agnostic_nms`): drop scores below the
//! threshold, keep the `pre_max_size` best, greedily suppress boxes whose BEV IoU with a kept box
//! is strictly greater than `iou_threshold`, return at most `post_max_size` indices, best first.

use serde::{Deserialize, Serialize};

use crate::boxes::Box3d;
use crate::iou::BevFootprint;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NmsConfig {
    pub iou_threshold: f64,
    pub score_threshold: f64,
    pub pre_max_size: usize,
    pub post_max_size: usize,
}

impl Default for NmsConfig {
    /// OpenPCDet's PointPillars test-time defaults.
    fn default() -> Self {
        Self { iou_threshold: 0.01, score_threshold: 0.1, pre_max_size: 4096, post_max_size: 500 }
    }
}

/// Indices into `boxes` of the kept detections, in descending score order. Ties keep input order.
pub fn nms(boxes: &[Box3d], scores: &[f64], cfg: &NmsConfig) -> Vec<usize> {
    assert_eq!(boxes.len(), scores.len(), "nms: one score per box");
    let mut order: Vec<usize> = (0..boxes.len()).filter(|&i| scores[i] >= cfg.score_threshold).collect();
    order.sort_by(|&i, &j| scores[j].total_cmp(&scores[i]));
    order.truncate(cfg.pre_max_size);
    let prints: Vec<BevFootprint> = order.iter().map(|&i| BevFootprint::new(&boxes[i])).collect();
    let mut keep: Vec<usize> = Vec::new();
    let mut suppressed = vec![false; order.len()];
    for k in 0..order.len() {
        if suppressed[k] {
            continue;
        }
        let bk = &prints[k];
        keep.push(order[k]);
        if keep.len() == cfg.post_max_size {
            break;
        }
        for (m, s) in suppressed.iter_mut().enumerate().skip(k + 1) {
            if !*s && bk.iou_exceeds(&prints[m], cfg.iou_threshold) {
                *s = true;
            }
        }
    }
    keep
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::iou::bev_iou;

    fn b(x: f64, y: f64) -> Box3d {
        Box3d::new(x, y, 0.0, 4.0, 2.0, 1.5, 0.0)
    }

    #[test]
    fn suppresses_overlaps_keeps_order() {
        let boxes = [b(0.0, 0.0), b(0.5, 0.0), b(10.0, 0.0), b(10.2, 0.1), b(30.0, 0.0)];
        let scores = [0.9, 0.95, 0.3, 0.8, 0.05];
        let cfg = NmsConfig { iou_threshold: 0.1, score_threshold: 0.1, pre_max_size: 100, post_max_size: 100 };
        assert_eq!(nms(&boxes, &scores, &cfg), vec![1, 3]);
    }

    #[test]
    fn threshold_is_strict_and_limits_apply() {
        // Two boxes with BEV IoU exactly 1/3: shifted by half their length.
        let boxes = [b(0.0, 0.0), b(2.0, 0.0), b(50.0, 0.0)];
        let scores = [0.9, 0.8, 0.7];
        let iou = bev_iou(&boxes[0], &boxes[1]);
        assert!((iou - 1.0 / 3.0).abs() < 1e-12);
        let cfg = NmsConfig { iou_threshold: iou, score_threshold: 0.0, pre_max_size: 10, post_max_size: 10 };
        assert_eq!(nms(&boxes, &scores, &cfg), vec![0, 1, 2]);
        let cfg = NmsConfig { post_max_size: 2, ..cfg };
        assert_eq!(nms(&boxes, &scores, &cfg), vec![0, 1]);
        let cfg = NmsConfig { pre_max_size: 1, ..cfg };
        assert_eq!(nms(&boxes, &scores, &cfg), vec![0]);
    }

    #[test]
    fn empty_input() {
        assert!(nms(&[], &[], &NmsConfig::default()).is_empty());
    }
}
