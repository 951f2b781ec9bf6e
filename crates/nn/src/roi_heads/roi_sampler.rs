//! RoI sampling for training the second stage, with OpenPCDet `ProposalTargetLayer` semantics
//! (Voxel R-CNN settings):
//!
//! - candidates: the frame's proposals, plus its GT boxes (`add_gt_to_proposals`, so every GT has
//!   at least one perfect RoI; OpenPCDet's layer does not do this, Faster R-CNN-style samplers
//!   do);
//! - each candidate's IoU is its largest exact 3D IoU with a GT box of the same class
//!   (`class_aware`, OpenPCDet `SAMPLE_ROI_BY_EACH_CLASS`), the matched GT that argmax;
//! - foreground: IoU ≥ min(`reg_fg_thresh`, `cls_fg_thresh`); hard background: IoU in
//!   [`cls_bg_thresh_lo`, `reg_fg_thresh`); easy background: IoU < `cls_bg_thresh_lo`;
//! - `roi_per_image` RoIs: up to round(`fg_ratio`·N) foreground without replacement, the rest
//!   background with replacement, `hard_bg_ratio` of it hard (when there are both kinds); only
//!   foreground (drawn with replacement) when there is no background;
//! - targets: regression where IoU > `reg_fg_thresh`; IoU-guided score
//!   `clip((IoU − cls_bg_thresh)/(cls_fg_thresh − cls_bg_thresh), 0, 1)`;
//! - ignored boxes (self-training pseudo-labels of middling score): a candidate that is not
//!   foreground and whose IoU with an ignored box, matched like GT (same class when
//!   `class_aware`), reaches [`RoiSamplerConfig::ignore_thresh`] (it would not be background if
//!   that box were GT) is neither foreground nor background: it is never sampled. Ignored boxes
//!   are not added to the candidates.
//!
//! Deterministic for a given [`ChaCha8Rng`] state. Runs in Rust on the CPU ([`RoiSamplerConfig::sample`]
//! per frame, [`RoiBatchTargets::collate`] into tensors).

use pi3det_geometry::{iou_3d_matrix, Box3d};
use rand::seq::index;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use tch::{Device, Tensor};

use super::proposal::Proposals;
use super::roi_coder::RoiCoder;
use crate::error::{NnError, Result};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoiSamplerConfig {
    pub roi_per_image: usize,
    pub fg_ratio: f64,
    pub reg_fg_thresh: f64,
    pub cls_fg_thresh: f64,
    pub cls_bg_thresh: f64,
    /// Easy background below this IoU.
    pub cls_bg_thresh_lo: f64,
    pub hard_bg_ratio: f64,
    /// Match RoIs only to GT of their own class.
    pub class_aware: bool,
    pub add_gt_to_proposals: bool,
}

impl Default for RoiSamplerConfig {
    /// Voxel R-CNN's `TARGET_CONFIG` in OpenPCDet.
    fn default() -> Self {
        Self {
            roi_per_image: 128,
            fg_ratio: 0.5,
            reg_fg_thresh: 0.55,
            cls_fg_thresh: 0.75,
            cls_bg_thresh: 0.25,
            cls_bg_thresh_lo: 0.1,
            hard_bg_ratio: 0.8,
            class_aware: true,
            add_gt_to_proposals: true,
        }
    }
}

/// What a sampled RoI is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RoiCategory {
    Foreground,
    HardBackground,
    EasyBackground,
    /// No candidate at all in the frame (no proposal, no GT): a row that no loss looks at.
    Padding,
}

/// The sampled RoIs of one frame (`roi_per_image` rows) and their targets.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FrameSample {
    /// Sampled RoIs in the detector's frame.
    pub rois: Vec<Box3d>,
    pub roi_scores: Vec<f64>,
    /// Class index, −1 on padding.
    pub roi_labels: Vec<i64>,
    /// Index of each row in the candidate list: `< proposals.len()` a proposal, else GT
    /// `k − proposals.len()` (added GT); −1 on padding.
    pub source: Vec<i64>,
    /// Matched GT (index into the frame's GT list, −1 when the IoU is 0) and its box (the RoI
    /// itself when unmatched, so the regression target is zero).
    pub gt_index: Vec<i64>,
    pub gt_boxes: Vec<Box3d>,
    /// IoU with the matched GT.
    pub ious: Vec<f64>,
    pub category: Vec<RoiCategory>,
    /// IoU > `reg_fg_thresh`.
    pub reg_valid: Vec<bool>,
    /// IoU-guided score target in [0, 1].
    pub iou_targets: Vec<f32>,
    /// Rows the score loss uses (all but padding).
    pub cls_valid: Vec<bool>,
}

impl FrameSample {
    pub fn len(&self) -> usize {
        self.rois.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rois.is_empty()
    }

    pub fn count(&self, c: RoiCategory) -> usize {
        self.category.iter().filter(|&&k| k == c).count()
    }
}

impl RoiSamplerConfig {
    pub fn validate(&self) -> Result<()> {
        let unit = |name: &str, v: f64| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(NnError::config("roi_head.sampler", format!("roi sampler: {name} {v} is not in [0, 1]")))
            }
        };
        if self.roi_per_image == 0 {
            return Err(NnError::config("roi_head.sampler", "roi sampler: roi_per_image must be positive"));
        }
        unit("fg_ratio", self.fg_ratio)?;
        unit("reg_fg_thresh", self.reg_fg_thresh)?;
        unit("cls_fg_thresh", self.cls_fg_thresh)?;
        unit("cls_bg_thresh", self.cls_bg_thresh)?;
        unit("cls_bg_thresh_lo", self.cls_bg_thresh_lo)?;
        unit("hard_bg_ratio", self.hard_bg_ratio)?;
        if self.cls_bg_thresh >= self.cls_fg_thresh {
            return Err(NnError::config("roi_head.sampler", "roi sampler: cls_bg_thresh must be below cls_fg_thresh"));
        }
        if self.cls_bg_thresh_lo > self.reg_fg_thresh {
            return Err(NnError::config(
                "roi_head.sampler",
                "roi sampler: cls_bg_thresh_lo must not exceed reg_fg_thresh",
            ));
        }
        Ok(())
    }

    /// IoU threshold of the foreground.
    pub fn fg_thresh(&self) -> f64 {
        self.reg_fg_thresh.min(self.cls_fg_thresh)
    }

    /// IoU with an ignored box from which a candidate is left out: the top of hard background
    /// (`reg_fg_thresh`), the IoU from which a RoI is no longer background.
    pub fn ignore_thresh(&self) -> f64 {
        self.reg_fg_thresh
    }

    /// The IoU-guided score target of an IoU.
    pub fn iou_target(&self, iou: f64) -> f32 {
        ((iou - self.cls_bg_thresh) / (self.cls_fg_thresh - self.cls_bg_thresh)).clamp(0.0, 1.0) as f32
    }

    /// Per candidate: best IoU and the GT it belongs to (−1 when no GT overlaps). GT boxes with a
    /// non-finite value or a non-positive size are never matched.
    pub fn match_candidates(
        &self,
        cands: &[Box3d],
        cand_labels: &[usize],
        gt: &[Box3d],
        gt_classes: &[usize],
    ) -> (Vec<f64>, Vec<i64>) {
        let usable: Vec<usize> = (0..gt.len())
            .filter(|&g| {
                let a = gt[g].to_array();
                a.iter().all(|v| v.is_finite()) && a[3] > 0.0 && a[4] > 0.0 && a[5] > 0.0
            })
            .collect();
        let gt_boxes: Vec<Box3d> = usable.iter().map(|&g| gt[g]).collect();
        let m = iou_3d_matrix(cands, &gt_boxes);
        let mut best = vec![0.0; cands.len()];
        let mut arg = vec![-1i64; cands.len()];
        for (r, (b, a)) in best.iter_mut().zip(arg.iter_mut()).enumerate() {
            for (k, &g) in usable.iter().enumerate() {
                if self.class_aware && gt_classes[g] != cand_labels[r] {
                    continue;
                }
                let v = m.get(r, k);
                if v > *b {
                    *b = v;
                    *a = g as i64;
                }
            }
        }
        (best, arg)
    }

    /// Samples `roi_per_image` RoIs of one frame from its proposals and GT (`gt_classes[k]` the
    /// class index of `gt[k]`), leaving out the candidates on `ignored` boxes (classes
    /// `ignored_classes`; see the module docs). Errors when a box list and its class list differ
    /// in length.
    pub fn sample(
        &self,
        proposals: &Proposals,
        gt: &[Box3d],
        gt_classes: &[usize],
        ignored: &[Box3d],
        ignored_classes: &[usize],
        rng: &mut ChaCha8Rng,
    ) -> Result<FrameSample> {
        if gt.len() != gt_classes.len() {
            return Err(NnError::Input(format!("roi sampler: {} GT boxes, {} classes", gt.len(), gt_classes.len())));
        }
        if ignored.len() != ignored_classes.len() {
            return Err(NnError::Input(format!(
                "roi sampler: {} ignored boxes, {} classes",
                ignored.len(),
                ignored_classes.len()
            )));
        }
        let mut cands = proposals.boxes.clone();
        let mut scores = proposals.scores.clone();
        let mut labels = proposals.labels.clone();
        if self.add_gt_to_proposals {
            for (b, &c) in gt.iter().zip(gt_classes) {
                let a = b.to_array();
                if a.iter().all(|v| v.is_finite()) && a[3] > 0.0 && a[4] > 0.0 && a[5] > 0.0 {
                    cands.push(b.with_wrapped_heading());
                    scores.push(1.0);
                    labels.push(c);
                } else {
                    // Keep the indices of `source` aligned with the GT list: an unusable GT is
                    // never a candidate, but its slot exists.
                    cands.push(Box3d::default());
                    scores.push(f64::NEG_INFINITY);
                    labels.push(c);
                }
            }
        }
        let (ious, gt_of) = self.match_candidates(&cands, &labels, gt, gt_classes);
        let fg_thresh = self.fg_thresh();
        let on_ignored = if ignored.is_empty() {
            vec![false; cands.len()]
        } else {
            let (ign, _) = self.match_candidates(&cands, &labels, ignored, ignored_classes);
            (0..cands.len()).map(|k| ious[k] < fg_thresh && ign[k] >= self.ignore_thresh()).collect()
        };
        let usable: Vec<usize> =
            (0..cands.len()).filter(|&k| scores[k] > f64::NEG_INFINITY && !on_ignored[k]).collect();

        let fg: Vec<usize> = usable.iter().copied().filter(|&k| ious[k] >= fg_thresh).collect();
        let easy: Vec<usize> = usable.iter().copied().filter(|&k| ious[k] < self.cls_bg_thresh_lo).collect();
        let hard: Vec<usize> = usable
            .iter()
            .copied()
            .filter(|&k| ious[k] >= self.cls_bg_thresh_lo && ious[k] < self.reg_fg_thresh)
            .collect();
        let n = self.roi_per_image;
        let with_replacement = |pool: &[usize], count: usize, rng: &mut ChaCha8Rng| -> Vec<usize> {
            (0..count).map(|_| pool[rng.random_range(0..pool.len())]).collect()
        };
        let bg_count = hard.len() + easy.len();
        let mut picked: Vec<usize> = Vec::with_capacity(n);
        if !fg.is_empty() && bg_count > 0 {
            let fg_per_image = (self.fg_ratio * n as f64).round() as usize;
            let take = fg_per_image.min(fg.len());
            picked.extend(index::sample(rng, fg.len(), take).into_iter().map(|i| fg[i]));
            picked.extend(self.sample_bg(&hard, &easy, n - take, rng, with_replacement));
        } else if !fg.is_empty() {
            picked.extend(with_replacement(&fg, n, rng));
        } else if bg_count > 0 {
            picked.extend(self.sample_bg(&hard, &easy, n, rng, with_replacement));
        }

        let mut s = FrameSample::default();
        for &k in &picked {
            let iou = ious[k];
            let g = gt_of[k];
            s.rois.push(cands[k]);
            s.roi_scores.push(scores[k]);
            s.roi_labels.push(labels[k] as i64);
            s.source.push(k as i64);
            s.gt_index.push(g);
            s.gt_boxes.push(if g >= 0 { gt[g as usize] } else { cands[k] });
            s.ious.push(iou);
            s.category.push(if iou >= fg_thresh {
                RoiCategory::Foreground
            } else if iou >= self.cls_bg_thresh_lo {
                RoiCategory::HardBackground
            } else {
                RoiCategory::EasyBackground
            });
            s.reg_valid.push(iou > self.reg_fg_thresh && g >= 0);
            s.iou_targets.push(self.iou_target(iou));
            s.cls_valid.push(true);
        }
        while s.rois.len() < n {
            s.rois.push(Box3d::default());
            s.roi_scores.push(0.0);
            s.roi_labels.push(-1);
            s.source.push(-1);
            s.gt_index.push(-1);
            s.gt_boxes.push(Box3d::default());
            s.ious.push(0.0);
            s.category.push(RoiCategory::Padding);
            s.reg_valid.push(false);
            s.iou_targets.push(0.0);
            s.cls_valid.push(false);
        }
        Ok(s)
    }

    /// OpenPCDet `sample_bg_inds`: `count` background candidates with replacement, hard ones
    /// `min(⌊count·hard_bg_ratio⌋, #hard)` of them when both kinds exist.
    fn sample_bg(
        &self,
        hard: &[usize],
        easy: &[usize],
        count: usize,
        rng: &mut ChaCha8Rng,
        draw: impl Fn(&[usize], usize, &mut ChaCha8Rng) -> Vec<usize>,
    ) -> Vec<usize> {
        match (hard.is_empty(), easy.is_empty()) {
            (false, false) => {
                let n_hard = ((count as f64 * self.hard_bg_ratio) as usize).min(hard.len());
                let mut v = draw(hard, n_hard, rng);
                v.extend(draw(easy, count - n_hard, rng));
                v
            }
            (false, true) => draw(hard, count, rng),
            (true, false) => draw(easy, count, rng),
            (true, true) => Vec::new(),
        }
    }
}

/// Sampled RoIs and targets of a batch (`N = roi_per_image`), on the CPU until moved.
#[derive(Debug)]
pub struct RoiBatchTargets {
    /// `[B, N, 7]` f32 RoIs (the input of [`super::RoiHead::forward_t`]).
    pub rois: Tensor,
    /// `[B, N]` f32 first-stage scores; `[B, N]` i64 labels (−1 padding).
    pub roi_scores: Tensor,
    pub roi_labels: Tensor,
    /// `[B, N, 7]` f32 matched GT in the detector's frame.
    pub gt_of_rois: Tensor,
    /// `[B, N, 7]` f32 [`RoiCoder`] codes of the matched GT against the RoI (zero where not
    /// regressed).
    pub reg_targets: Tensor,
    /// `[B, N]` f32 1 where regressed (IoU > `reg_fg_thresh`), else 0.
    pub reg_valid: Tensor,
    /// `[B, N]` f32 score targets and `[B, N]` f32 1 where the score loss counts.
    pub iou_targets: Tensor,
    pub cls_valid: Tensor,
    /// `[B, N]` f32 IoU with the matched GT.
    pub ious: Tensor,
}

impl RoiBatchTargets {
    /// Stacks frames' samples (all of the same length). Errors on differing lengths.
    pub fn collate(frames: &[FrameSample]) -> Result<Self> {
        let n = frames.first().map(FrameSample::len).unwrap_or(0);
        if n == 0 || frames.iter().any(|f| f.len() != n) {
            return Err(NnError::Input("roi targets: frames must have the same positive number of RoIs".into()));
        }
        let b = frames.len();
        let mut rois = Vec::with_capacity(b * n * 7);
        let mut gts = Vec::with_capacity(b * n * 7);
        let mut codes = Vec::with_capacity(b * n * 7);
        let (mut scores, mut labels, mut reg, mut tgt, mut cls, mut ious) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for f in frames {
            for k in 0..n {
                rois.extend(f.rois[k].to_array().map(|v| v as f32));
                gts.extend(f.gt_boxes[k].to_array().map(|v| v as f32));
                codes.extend(if f.reg_valid[k] { RoiCoder::encode(&f.gt_boxes[k], &f.rois[k]) } else { [0.0; 7] });
                scores.push(f.roi_scores[k] as f32);
                labels.push(f.roi_labels[k]);
                reg.push(f32::from(u8::from(f.reg_valid[k])));
                tgt.push(f.iou_targets[k]);
                cls.push(f32::from(u8::from(f.cls_valid[k])));
                ious.push(f.ious[k] as f32);
            }
        }
        let (b, n) = (b as i64, n as i64);
        let t2 = |v: &[f32]| Tensor::from_slice(v).view([b, n]);
        let t3 = |v: &[f32]| Tensor::from_slice(v).view([b, n, 7]);
        Ok(Self {
            rois: t3(&rois),
            roi_scores: t2(&scores),
            roi_labels: Tensor::from_slice(&labels).view([b, n]),
            gt_of_rois: t3(&gts),
            reg_targets: t3(&codes),
            reg_valid: t2(&reg),
            iou_targets: t2(&tgt),
            cls_valid: t2(&cls),
            ious: t2(&ious),
        })
    }

    pub fn to_device(&self, d: Device) -> Self {
        Self {
            rois: self.rois.to_device(d),
            roi_scores: self.roi_scores.to_device(d),
            roi_labels: self.roi_labels.to_device(d),
            gt_of_rois: self.gt_of_rois.to_device(d),
            reg_targets: self.reg_targets.to_device(d),
            reg_valid: self.reg_valid.to_device(d),
            iou_targets: self.iou_targets.to_device(d),
            cls_valid: self.cls_valid.to_device(d),
            ious: self.ious.to_device(d),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::iou_3d;
    use rand::SeedableRng;

    fn jitter(b: &Box3d, rng: &mut ChaCha8Rng, s: f64) -> Box3d {
        Box3d {
            x: b.x + rng.random_range(-s..s),
            y: b.y + rng.random_range(-s..s),
            z: b.z + rng.random_range(-0.3 * s..0.3 * s),
            dx: b.dx * rng.random_range(0.8..1.2),
            dy: b.dy * rng.random_range(0.8..1.2),
            dz: b.dz * rng.random_range(0.8..1.2),
            heading: b.heading + rng.random_range(-0.3..0.3),
        }
    }

    fn scene(rng: &mut ChaCha8Rng, proposals: usize) -> (Proposals, Vec<Box3d>, Vec<usize>) {
        let gt = vec![
            Box3d::new(5.0, 2.0, 0.8, 4.2, 1.9, 1.6, 0.3),
            Box3d::new(12.0, -4.0, 0.8, 4.0, 1.8, 1.5, -2.9),
            Box3d::new(7.0, 6.0, 0.9, 0.8, 0.6, 1.7, 1.0),
            Box3d::new(7.6, 6.1, 0.9, 0.7, 0.6, 1.7, 1.2),
        ];
        let classes = vec![0, 0, 1, 1];
        let mut p = Proposals::default();
        for k in 0..proposals {
            let g = k % (gt.len() + 1);
            let (b, label) = if g == gt.len() {
                // Far from everything.
                (Box3d::new(rng.random_range(20.0..40.0), rng.random_range(-20.0..20.0), 0.8, 4.0, 1.8, 1.5, 0.0), 0)
            } else {
                let label = if k % 7 == 0 { 1 - classes[g] } else { classes[g] }; // some with the wrong class
                (jitter(&gt[g], rng, [0.3, 1.0, 2.5][k % 3] * gt[g].dy), label)
            };
            p.boxes.push(b);
            p.scores.push(rng.random_range(0.0..1.0));
            p.labels.push(label);
        }
        (p, gt, classes)
    }

    /// Brute force: the category counts the sampler must produce, from the candidates' IoUs.
    fn expected_counts(cfg: &RoiSamplerConfig, ious: &[f64]) -> (usize, usize, usize) {
        let n = cfg.roi_per_image;
        let fg = ious.iter().filter(|&&v| v >= cfg.fg_thresh()).count();
        let hard = ious.iter().filter(|&&v| v >= cfg.cls_bg_thresh_lo && v < cfg.reg_fg_thresh).count();
        let easy = ious.iter().filter(|&&v| v < cfg.cls_bg_thresh_lo).count();
        let bg = hard + easy;
        let split_bg = |count: usize| match (hard > 0, easy > 0) {
            (true, true) => {
                let h = ((count as f64 * cfg.hard_bg_ratio) as usize).min(hard);
                (h, count - h)
            }
            (true, false) => (count, 0),
            (false, true) => (0, count),
            (false, false) => (0, 0),
        };
        if fg > 0 && bg > 0 {
            let f = ((cfg.fg_ratio * n as f64).round() as usize).min(fg);
            let (h, e) = split_bg(n - f);
            (f, h, e)
        } else if fg > 0 {
            (n, 0, 0)
        } else {
            let (h, e) = split_bg(n);
            (0, h, e)
        }
    }

    fn check_frame(cfg: &RoiSamplerConfig, p: &Proposals, gt: &[Box3d], classes: &[usize], s: &FrameSample) {
        let n = cfg.roi_per_image;
        assert_eq!(s.len(), n);
        let mut cands = p.boxes.clone();
        let mut labels = p.labels.clone();
        if cfg.add_gt_to_proposals {
            cands.extend(gt.iter().map(|b| b.with_wrapped_heading()));
            labels.extend_from_slice(classes);
        }
        // Brute-force class-aware IoU and argmax.
        let brute: Vec<(f64, i64)> = cands
            .iter()
            .zip(&labels)
            .map(|(c, &l)| {
                let mut best = (0.0, -1i64);
                for (g, (b, &k)) in gt.iter().zip(classes).enumerate() {
                    let v = iou_3d(c, b);
                    if (!cfg.class_aware || k == l) && v > best.0 {
                        best = (v, g as i64);
                    }
                }
                best
            })
            .collect();
        let ious: Vec<f64> = brute.iter().map(|b| b.0).collect();
        let (f, h, e) = if cands.is_empty() { (0, 0, 0) } else { expected_counts(cfg, &ious) };
        assert_eq!(s.count(RoiCategory::Foreground), f);
        assert_eq!(s.count(RoiCategory::HardBackground), h);
        assert_eq!(s.count(RoiCategory::EasyBackground), e);
        assert_eq!(s.count(RoiCategory::Padding), n - f - h - e);
        // Foreground without replacement while there is background.
        let fg_src: Vec<i64> =
            (0..n).filter(|&k| s.category[k] == RoiCategory::Foreground).map(|k| s.source[k]).collect();
        if h + e > 0 {
            let mut u = fg_src.clone();
            u.sort();
            u.dedup();
            assert_eq!(u.len(), fg_src.len(), "foreground drawn twice");
        }
        for k in 0..n {
            if s.category[k] == RoiCategory::Padding {
                assert!(!s.cls_valid[k] && !s.reg_valid[k] && s.source[k] == -1 && s.roi_labels[k] == -1);
                continue;
            }
            let src = s.source[k];
            assert!(src >= 0 && (src as usize) < cands.len(), "sampled index {src} out of range");
            let (iou, g) = brute[src as usize];
            assert_eq!(s.rois[k], cands[src as usize]);
            assert_eq!(s.roi_labels[k], labels[src as usize] as i64);
            assert!((s.ious[k] - iou).abs() < 1e-12);
            assert_eq!(s.gt_index[k], g, "matched GT is the argmax");
            if g >= 0 {
                assert_eq!(s.gt_boxes[k], gt[g as usize]);
                if cfg.class_aware {
                    assert_eq!(classes[g as usize] as i64, s.roi_labels[k], "class-aware match");
                }
            }
            match s.category[k] {
                RoiCategory::Foreground => assert!(s.ious[k] >= 0.55),
                RoiCategory::HardBackground => assert!(s.ious[k] >= 0.1 && s.ious[k] < 0.55),
                RoiCategory::EasyBackground => assert!(s.ious[k] < 0.1),
                RoiCategory::Padding => unreachable!(),
            }
            assert_eq!(s.reg_valid[k], s.ious[k] > 0.55);
            let want = ((s.ious[k] - 0.25) / 0.5).clamp(0.0, 1.0) as f32;
            assert!((s.iou_targets[k] - want).abs() < 1e-6);
            assert!(s.cls_valid[k]);
        }
    }

    #[test]
    fn sampling_matches_brute_force_reference() {
        let cfg = RoiSamplerConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for (proposals, add_gt, class_aware) in
            [(300, true, true), (40, true, true), (300, false, true), (300, true, false), (6, false, true)]
        {
            let cfg = RoiSamplerConfig { add_gt_to_proposals: add_gt, class_aware, ..cfg.clone() };
            let (p, gt, classes) = scene(&mut rng, proposals);
            let s = cfg.sample(&p, &gt, &classes, &[], &[], &mut rng).unwrap();
            check_frame(&cfg, &p, &gt, &classes, &s);
            if add_gt {
                assert!(s.count(RoiCategory::Foreground) > 0);
            }
        }
        // Small batches exercise every branch: only fg, only bg, both.
        let (p, gt, classes) = scene(&mut rng, 300);
        let only_fg = Proposals { boxes: gt.clone(), scores: vec![0.5; 4], labels: classes.clone() };
        let cfg = RoiSamplerConfig { roi_per_image: 16, ..cfg };
        let s = cfg.sample(&only_fg, &gt, &classes, &[], &[], &mut rng).unwrap();
        check_frame(&cfg, &only_fg, &gt, &classes, &s);
        assert_eq!(s.count(RoiCategory::Foreground), 16);
        let s = cfg.sample(&p, &[], &[], &[], &[], &mut rng).unwrap();
        check_frame(&cfg, &p, &[], &[], &s);
        assert_eq!(s.count(RoiCategory::EasyBackground), 16, "no GT: everything is easy background");
        assert!(s.gt_index.iter().all(|&g| g == -1) && s.reg_valid.iter().all(|&v| !v));
    }

    #[test]
    fn empty_frames_and_determinism() {
        let cfg = RoiSamplerConfig { roi_per_image: 8, ..Default::default() };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        // Nothing at all: padding rows only.
        let s = cfg.sample(&Proposals::default(), &[], &[], &[], &[], &mut rng).unwrap();
        assert_eq!(s.count(RoiCategory::Padding), 8);
        check_frame(&cfg, &Proposals::default(), &[], &[], &s);
        // No proposals but GT: the GT themselves are the foreground.
        let gt = [Box3d::new(0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0)];
        let s = cfg.sample(&Proposals::default(), &gt, &[0], &[], &[], &mut rng).unwrap();
        assert_eq!(s.count(RoiCategory::Foreground), 8);
        assert!(s.ious.iter().all(|&v| (v - 1.0).abs() < 1e-9));
        assert!(s.iou_targets.iter().all(|&v| v == 1.0));
        // A degenerate GT is neither a candidate nor a match.
        let bad = [Box3d::new(0.0, 0.0, 0.0, 0.0, 2.0, 1.5, 0.0)];
        let s = cfg.sample(&Proposals::default(), &bad, &[0], &[], &[], &mut rng).unwrap();
        assert_eq!(s.count(RoiCategory::Padding), 8);
        assert!(cfg.sample(&Proposals::default(), &gt, &[], &[], &[], &mut rng).is_err());
        // Same seed, same sample.
        let (p, gt, classes) = scene(&mut ChaCha8Rng::seed_from_u64(5), 200);
        let a = cfg.sample(&p, &gt, &classes, &[], &[], &mut ChaCha8Rng::seed_from_u64(9)).unwrap();
        let b = cfg.sample(&p, &gt, &classes, &[], &[], &mut ChaCha8Rng::seed_from_u64(9)).unwrap();
        assert_eq!(a, b);
        let c = cfg.sample(&p, &gt, &classes, &[], &[], &mut ChaCha8Rng::seed_from_u64(10)).unwrap();
        assert_ne!(a.source, c.source);
    }

    /// Proposals on an ignored car (labelled car) are never sampled; labelled pedestrian they
    /// are background as before; proposals that are foreground for a real car stay foreground
    /// even on an ignored box.
    #[test]
    fn proposals_on_ignored_boxes_are_not_sampled() {
        let cfg = RoiSamplerConfig { roi_per_image: 64, ..Default::default() };
        let gt = [Box3d::new(5.0, 2.0, 0.8, 4.2, 1.9, 1.6, 0.3)];
        let far_car = Box3d::new(15.0, -4.0, 0.8, 4.0, 1.8, 1.5, -0.4);
        // The far car, and a copy of the real car (a duplicate pseudo-label).
        let ignored = [far_car, Box3d { x: 5.1, ..gt[0] }];
        let mut p = Proposals::default();
        let offsets = [-0.3, -0.15, 0.0, 0.15, 0.3];
        for (label, b) in [(0, far_car), (1, far_car), (0, gt[0])] {
            for dx in offsets {
                p.boxes.push(Box3d { x: b.x + dx, y: b.y - 0.5 * dx, ..b });
                p.scores.push(0.5);
                p.labels.push(label);
            }
        }
        for k in 0..5 {
            p.boxes.push(Box3d::new(-20.0 + 3.0 * k as f64, 10.0, 0.8, 4.0, 1.8, 1.5, 0.0));
            p.scores.push(0.2);
            p.labels.push(0);
        }
        let excluded: Vec<i64> = (0..5).collect();
        for k in 0..5 {
            assert!(iou_3d(&p.boxes[k], &far_car) >= cfg.ignore_thresh());
            assert!(iou_3d(&p.boxes[10 + k], &ignored[1]) >= cfg.ignore_thresh());
        }
        let plain = cfg.sample(&p, &gt, &[0], &[], &[], &mut ChaCha8Rng::seed_from_u64(4)).unwrap();
        check_frame(&cfg, &p, &gt, &[0], &plain);
        assert!(plain.source.iter().any(|s| excluded.contains(s)), "sampled as background without the band");
        let s = cfg.sample(&p, &gt, &[0], &ignored, &[0, 0], &mut ChaCha8Rng::seed_from_u64(4)).unwrap();
        assert!(!s.source.iter().any(|s| excluded.contains(s)), "{:?}", s.source);
        assert_eq!(s.count(RoiCategory::Foreground), plain.count(RoiCategory::Foreground));
        assert!(s.source.iter().any(|&k| (5..10).contains(&k)), "a pedestrian label on an ignored car is background");
        for k in 0..s.len() {
            if (5..10).contains(&s.source[k]) {
                assert_eq!(s.category[k], RoiCategory::EasyBackground);
            }
        }
        // Every proposal ignored: nothing but the GT itself is left.
        let only = Proposals { boxes: p.boxes[..5].to_vec(), scores: vec![0.5; 5], labels: vec![0; 5] };
        let s = cfg.sample(&only, &gt, &[0], &ignored[..1], &[0], &mut ChaCha8Rng::seed_from_u64(4)).unwrap();
        assert!(s.source.iter().all(|&k| k == 5), "{:?}", s.source);
        let none = cfg.sample(&only, &[], &[], &ignored[..1], &[0], &mut ChaCha8Rng::seed_from_u64(4)).unwrap();
        assert_eq!(none.count(RoiCategory::Padding), 64);
        assert!(cfg.sample(&only, &gt, &[0], &ignored, &[0], &mut ChaCha8Rng::seed_from_u64(4)).is_err());
    }

    #[test]
    fn collate_encodes_regression_targets() {
        let cfg = RoiSamplerConfig { roi_per_image: 32, ..Default::default() };
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let (p, gt, classes) = scene(&mut rng, 100);
        let a = cfg.sample(&p, &gt, &classes, &[], &[], &mut rng).unwrap();
        let b = cfg.sample(&Proposals::default(), &[], &[], &[], &[], &mut rng).unwrap();
        let t = RoiBatchTargets::collate(&[a.clone(), b]).unwrap();
        assert_eq!(t.rois.size(), [2, 32, 7]);
        assert_eq!(t.reg_targets.size(), [2, 32, 7]);
        let codes: Vec<f32> = Vec::try_from(t.reg_targets.get(0).reshape([-1])).unwrap();
        for k in 0..32 {
            let c: [f32; 7] = codes[k * 7..k * 7 + 7].try_into().unwrap();
            if a.reg_valid[k] {
                let back = RoiCoder::decode(&c, &a.rois[k]);
                assert!(iou_3d(&back, &a.gt_boxes[k]) > 0.999);
            } else {
                assert!(c.iter().all(|&v| v == 0.0));
            }
        }
        let cls: Vec<f32> = Vec::try_from(t.cls_valid.get(1)).unwrap();
        assert!(cls.iter().all(|&v| v == 0.0));
        let short = cfg.clone();
        let short = RoiSamplerConfig { roi_per_image: 4, ..short };
        let c = short.sample(&p, &gt, &classes, &[], &[], &mut rng).unwrap();
        assert!(RoiBatchTargets::collate(&[a, c]).is_err());
        assert!(RoiBatchTargets::collate(&[]).is_err());
    }

    #[test]
    fn bad_config_is_an_error() {
        assert!(RoiSamplerConfig::default().validate().is_ok());
        assert!(RoiSamplerConfig { fg_ratio: 1.5, ..Default::default() }.validate().is_err());
        assert!(RoiSamplerConfig { roi_per_image: 0, ..Default::default() }.validate().is_err());
        assert!(RoiSamplerConfig { cls_bg_thresh: 0.8, ..Default::default() }.validate().is_err());
        assert!(RoiSamplerConfig { cls_bg_thresh_lo: 0.6, ..Default::default() }.validate().is_err());
    }
}
