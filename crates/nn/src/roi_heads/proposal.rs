//! Proposals for the second stage (OpenPCDet `RoIHeadTemplate.proposal_layer`): per frame, the
//! dense head's decoded candidates go through class-agnostic rotated NMS with their own limits —
//! many RoIs while training (the sampler picks from them), few at test time.
//!
//! Input: the candidates of one frame as Rust values ([`ProposalConfig::select`]) or as the
//! `(boxes [K, 7], scores [K], labels [K])` tensors the dense heads' `candidates` return
//! ([`ProposalConfig::select_tensors`]); the scores are probabilities (after the sigmoid), labels
//! class indices. Output: [`Proposals`] (Rust, best first) and, stacked over a batch,
//! [`ProposalBatch`] tensors.

use pi3det_geometry::{nms, Box3d, NmsConfig};
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::error::{NnError, Result};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProposalConfig {
    /// Candidates kept (by score) before NMS while training.
    pub nms_pre_max_train: usize,
    /// RoIs kept after NMS while training.
    pub nms_post_max_train: usize,
    pub nms_pre_max_test: usize,
    pub nms_post_max_test: usize,
    /// BEV IoU above which a lower-scored candidate is suppressed.
    pub nms_iou: f64,
    /// Candidates scoring below this are dropped before NMS.
    pub score_threshold: f64,
}

impl Default for ProposalConfig {
    /// OpenPCDet's two-stage RPN NMS (IoU 0.7) with CPU-sized limits (OpenPCDet: 9000 / 512
    /// train, 1024 / 100 test).
    fn default() -> Self {
        Self {
            nms_pre_max_train: 2048,
            nms_post_max_train: 512,
            nms_pre_max_test: 1024,
            nms_post_max_test: 100,
            nms_iou: 0.7,
            score_threshold: 0.0,
        }
    }
}

/// The proposals of one frame, best first.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Proposals {
    /// Boxes in the detector's frame, heading wrapped to `[−π, π)`.
    pub boxes: Vec<Box3d>,
    /// First-stage scores (probabilities).
    pub scores: Vec<f64>,
    /// Class indices.
    pub labels: Vec<usize>,
}

impl Proposals {
    pub fn len(&self) -> usize {
        self.boxes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.boxes.is_empty()
    }
}

impl ProposalConfig {
    pub fn validate(&self) -> Result<()> {
        if self.nms_pre_max_train == 0
            || self.nms_post_max_train == 0
            || self.nms_pre_max_test == 0
            || self.nms_post_max_test == 0
        {
            return Err(NnError::config(
                "roi_head.proposal",
                "roi proposal: nms_pre_max_* and nms_post_max_* must be positive",
            ));
        }
        if !(0.0..=1.0).contains(&self.nms_iou) {
            return Err(NnError::config(
                "roi_head.proposal",
                format!("roi proposal: nms_iou {} is not in [0, 1]", self.nms_iou),
            ));
        }
        if !self.score_threshold.is_finite() {
            return Err(NnError::config("roi_head.proposal", "roi proposal: score_threshold must be finite"));
        }
        Ok(())
    }

    /// The NMS settings of the training or the test limits.
    pub fn nms_config(&self, train: bool) -> NmsConfig {
        let (pre, post) = if train {
            (self.nms_pre_max_train, self.nms_post_max_train)
        } else {
            (self.nms_pre_max_test, self.nms_post_max_test)
        };
        NmsConfig {
            iou_threshold: self.nms_iou,
            score_threshold: self.score_threshold,
            pre_max_size: pre,
            post_max_size: post,
        }
    }

    /// Proposals of one frame from its candidates (boxes in the detector's frame). Candidates with
    /// a non-finite value, a negative size or a non-finite score are dropped first. Errors when
    /// the three slices differ in length.
    pub fn select(&self, boxes: &[Box3d], scores: &[f64], labels: &[usize], train: bool) -> Result<Proposals> {
        if boxes.len() != scores.len() || boxes.len() != labels.len() {
            return Err(NnError::Input(format!(
                "roi proposal: {} boxes, {} scores, {} labels",
                boxes.len(),
                scores.len(),
                labels.len()
            )));
        }
        let ok: Vec<usize> = (0..boxes.len())
            .filter(|&k| {
                let a = boxes[k].to_array();
                a.iter().all(|v| v.is_finite()) && a[3] >= 0.0 && a[4] >= 0.0 && a[5] >= 0.0 && scores[k].is_finite()
            })
            .collect();
        let b: Vec<Box3d> = ok.iter().map(|&k| boxes[k].with_wrapped_heading()).collect();
        let s: Vec<f64> = ok.iter().map(|&k| scores[k]).collect();
        let keep = nms(&b, &s, &self.nms_config(train));
        Ok(Proposals {
            boxes: keep.iter().map(|&k| b[k]).collect(),
            scores: keep.iter().map(|&k| s[k]).collect(),
            labels: keep.iter().map(|&k| labels[ok[k]]).collect(),
        })
    }

    /// [`select`](Self::select) on tensors (any device): `boxes [K, 7]`, `scores [K]`, `labels
    /// [K]` (integer class indices; negative ones are dropped).
    pub fn select_tensors(&self, boxes: &Tensor, scores: &Tensor, labels: &Tensor, train: bool) -> Result<Proposals> {
        let k = scores.numel();
        if boxes.numel() != 7 * k || labels.numel() != k {
            return Err(NnError::Input(format!(
                "roi proposal: boxes {:?}, scores {:?}, labels {:?} (want [K, 7], [K], [K])",
                boxes.size(),
                scores.size(),
                labels.size()
            )));
        }
        let b: Vec<f64> = Vec::try_from(boxes.to_device(Device::Cpu).to_kind(Kind::Double).reshape([-1]))?;
        let s: Vec<f64> = Vec::try_from(scores.to_device(Device::Cpu).to_kind(Kind::Double).reshape([-1]))?;
        let l: Vec<i64> = Vec::try_from(labels.to_device(Device::Cpu).to_kind(Kind::Int64).reshape([-1]))?;
        let keep: Vec<usize> = (0..k).filter(|&i| l[i] >= 0).collect();
        let boxes: Vec<Box3d> =
            keep.iter().map(|&i| Box3d::from_array(std::array::from_fn(|j| b[i * 7 + j]))).collect();
        let scores: Vec<f64> = keep.iter().map(|&i| s[i]).collect();
        let labels: Vec<usize> = keep.iter().map(|&i| l[i] as usize).collect();
        self.select(&boxes, &scores, &labels, train)
    }
}

/// Proposals of a batch, padded to the longest frame.
#[derive(Debug)]
pub struct ProposalBatch {
    /// `[B, N, 7]` f32, padding rows all zero (as OpenPCDet).
    pub rois: Tensor,
    /// `[B, N]` f32, 0 on padding.
    pub roi_scores: Tensor,
    /// `[B, N]` i64 class index, −1 on padding.
    pub roi_labels: Tensor,
    /// `[B, N]` bool, false on padding.
    pub valid: Tensor,
}

impl ProposalBatch {
    /// Stacks frames' proposals on the CPU; `N = max(1, longest frame)` so that no tensor is empty.
    pub fn collate(frames: &[Proposals]) -> Self {
        let n = frames.iter().map(Proposals::len).max().unwrap_or(0).max(1);
        Self::collate_to(frames, n)
    }

    /// [`collate`](Self::collate) to exactly `n` rows per frame (a traced second stage has a
    /// fixed RoI count); frames with more proposals keep their first `n`.
    pub fn collate_to(frames: &[Proposals], n: usize) -> Self {
        let b = frames.len();
        let n = n.max(1);
        let mut rois = vec![0f32; b * n * 7];
        let mut scores = vec![0f32; b * n];
        let mut labels = vec![-1i64; b * n];
        let mut valid = vec![false; b * n];
        for (f, p) in frames.iter().enumerate() {
            for k in 0..p.len().min(n) {
                let row = f * n + k;
                for (dst, v) in rois[row * 7..row * 7 + 7].iter_mut().zip(p.boxes[k].to_array()) {
                    *dst = v as f32;
                }
                scores[row] = p.scores[k] as f32;
                labels[row] = p.labels[k] as i64;
                valid[row] = true;
            }
        }
        let (b, n) = (b as i64, n as i64);
        Self {
            rois: Tensor::from_slice(&rois).view([b, n, 7]),
            roi_scores: Tensor::from_slice(&scores).view([b, n]),
            roi_labels: Tensor::from_slice(&labels).view([b, n]),
            valid: Tensor::from_slice(&valid).view([b, n]),
        }
    }

    pub fn to_device(&self, d: Device) -> Self {
        Self {
            rois: self.rois.to_device(d),
            roi_scores: self.roi_scores.to_device(d),
            roi_labels: self.roi_labels.to_device(d),
            valid: self.valid.to_device(d),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn car(x: f64, y: f64, heading: f64) -> Box3d {
        Box3d::new(x, y, 0.8, 4.0, 1.8, 1.6, heading)
    }

    #[test]
    fn select_applies_nms_limits_and_drops_bad_candidates() {
        let cfg = ProposalConfig { nms_post_max_test: 2, ..Default::default() };
        let boxes = vec![
            car(0.0, 0.0, 0.0),
            car(0.1, 0.0, 0.0), // suppressed by the first (BEV IoU > 0.7)
            car(10.0, 0.0, 3.5),
            car(20.0, 0.0, 0.0),
            Box3d::new(f64::NAN, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0),
            Box3d::new(30.0, 0.0, 0.0, -1.0, 1.0, 1.0, 0.0),
        ];
        let scores = [0.9, 0.95, 0.5, 0.4, 0.99, 0.99];
        let labels = [0, 1, 1, 0, 0, 0];
        let test = cfg.select(&boxes, &scores, &labels, false).unwrap();
        assert_eq!(test.scores, vec![0.95, 0.5]);
        assert_eq!(test.labels, vec![1, 1]);
        assert!(test.boxes[1].heading < std::f64::consts::PI && test.boxes[1].heading >= -std::f64::consts::PI);
        let train = cfg.select(&boxes, &scores, &labels, true).unwrap();
        assert_eq!(train.scores, vec![0.95, 0.5, 0.4]);
        assert!(cfg.select(&boxes, &scores[..2], &labels, true).is_err());

        let t = cfg
            .select_tensors(
                &Tensor::from_slice(&boxes.iter().flat_map(|b| b.to_array().map(|v| v as f32)).collect::<Vec<_>>())
                    .view([6, 7]),
                &Tensor::from_slice(&scores.map(|v| v as f32)),
                &Tensor::from_slice(&labels.map(|v| v as i64)),
                true,
            )
            .unwrap();
        assert_eq!(t.labels, train.labels);
        assert_eq!(t.len(), 3);
        assert!(cfg
            .select_tensors(
                &Tensor::zeros([3, 7], (Kind::Float, Device::Cpu)),
                &Tensor::zeros([2], (Kind::Float, Device::Cpu)),
                &Tensor::zeros([3], (Kind::Int64, Device::Cpu)),
                true
            )
            .is_err());
    }

    #[test]
    fn batch_pads_with_minus_one_labels() {
        let cfg = ProposalConfig::default();
        let a = cfg.select(&[car(0.0, 0.0, 0.0), car(10.0, 0.0, 0.0)], &[0.9, 0.8], &[0, 1], false).unwrap();
        let empty = Proposals::default();
        let batch = ProposalBatch::collate(&[a, empty.clone()]);
        assert_eq!(batch.rois.size(), [2, 2, 7]);
        let labels: Vec<i64> = Vec::try_from(batch.roi_labels.view([-1])).unwrap();
        assert_eq!(labels, vec![0, 1, -1, -1]);
        let valid: Vec<bool> = Vec::try_from(batch.valid.view([-1])).unwrap();
        assert_eq!(valid, vec![true, true, false, false]);
        assert_eq!(f64::try_from(batch.rois.get(1).abs().sum(Kind::Float)).unwrap(), 0.0);
        assert!((f64::try_from(batch.rois.get(0).get(1).get(0)).unwrap() - 10.0).abs() < 1e-6);
        // All frames empty: one padding row, not an empty tensor.
        let batch = ProposalBatch::collate(&[empty]);
        assert_eq!(batch.rois.size(), [1, 1, 7]);
    }

    #[test]
    fn bad_config_is_an_error() {
        assert!(ProposalConfig::default().validate().is_ok());
        assert!(ProposalConfig { nms_iou: 1.5, ..Default::default() }.validate().is_err());
        assert!(ProposalConfig { nms_post_max_test: 0, ..Default::default() }.validate().is_err());
        let e = toml::from_str::<ProposalConfig>("nms_iou = 0.5\nbogus = 1").unwrap_err();
        assert!(e.to_string().contains("bogus"));
    }
}
