//! Pseudo-labels for Knowledge-Adaptation (ST3D's recipe, which Pi3DET-Net follows): the
//! pre-adapted detector runs on the target's unlabelled training frames (through Virtual
//! Platform Pose when it is on); boxes scoring at least `positive_score` teach like ground truth,
//! boxes between `ignore_score` and `positive_score` are *ignored* (anchors, centres and RoIs
//! matched to them leave both losses: [`pi3det_nn::preprocess::Preprocessor::with_ignore_score_below`]),
//! lower ones are dropped. They are written as `pseudo_labels.jsonl`, the detection format
//! `pi3det eval --det` scores against the target's ground truth, and [`quality`] measures their
//! precision and recall directly.

use std::collections::HashMap;
use std::sync::Arc;

use pi3det_data::{Dataset, FrameInfo, FrameMap, Mapped, Object};
use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};

use pi3det_nn::config::DetectorConfig;
use pi3det_nn::data_loader::Subset;
use pi3det_nn::detect::{self, FrameDetections};
use pi3det_nn::detector::Detector;
use pi3det_nn::error::{NnError, Result};
use pi3det_nn::preprocess::Preprocessor;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PseudoLabelConfig {
    /// Boxes at or above this score are positives.
    pub positive_score: f64,
    /// Boxes between this and `positive_score` are ignored; lower ones are dropped.
    pub ignore_score: f64,
    /// Regenerate the pseudo-labels with the current model every this many KA epochs (0: never).
    pub refresh_every: usize,
}

impl Default for PseudoLabelConfig {
    fn default() -> Self {
        Self { positive_score: 0.5, ignore_score: 0.2, refresh_every: 0 }
    }
}

impl PseudoLabelConfig {
    pub fn validate(&self) -> Result<()> {
        if !(0.0 <= self.ignore_score && self.ignore_score <= self.positive_score && self.positive_score < 1.0) {
            return Err(NnError::config(
                "pseudo_labels",
                format!(
                    "pseudo_labels: need 0 ≤ ignore_score ≤ positive_score < 1 (got {} and {})",
                    self.ignore_score, self.positive_score
                ),
            ));
        }
        Ok(())
    }
}

/// Detections of `det` on `subset` (frames prepared by `prep`), keeping boxes scoring at least
/// `cfg.ignore_score`; one entry per frame of `subset`, in its order.
pub fn generate(
    det: &Detector,
    prep: Arc<Preprocessor>,
    subset: &Subset,
    cfg: &PseudoLabelConfig,
    on_batch: &mut dyn FnMut(usize, usize),
) -> Result<Vec<FrameDetections>> {
    let (mut frames, _) = detect::detect_with(det, prep, subset, 4, true, on_batch)?;
    for f in &mut frames {
        f.objects.retain(|o| o.score.is_some_and(|s| s >= cfg.ignore_score));
    }
    Ok(frames)
}

/// Pseudo-labels for a dataset's frames, replacing their own annotations (frames without an
/// entry have none); [`subset`](Self::subset) reads the frames through them.
pub struct PseudoLabeled {
    inner: Arc<dyn Dataset>,
    labels: HashMap<usize, Vec<Object>>,
}

struct Labels(HashMap<usize, Vec<Object>>);

impl FrameMap for Labels {
    fn info(&self, index: usize, mut info: FrameInfo) -> FrameInfo {
        info.objects = self.0.get(&index).cloned().unwrap_or_default();
        info
    }
}

impl PseudoLabeled {
    /// `frames[k]` labels dataset frame `subset.indices[k]`.
    pub fn new(subset: &Subset, frames: &[FrameDetections]) -> Result<Self> {
        if frames.len() != subset.len() {
            return Err(NnError::Input(format!(
                "{} pseudo-labelled frames for a subset of {}",
                frames.len(),
                subset.len()
            )));
        }
        let labels = subset.indices.iter().zip(frames).map(|(&i, f)| (i, f.objects.clone())).collect();
        Ok(Self { inner: subset.dataset.clone(), labels })
    }

    /// The same frames as `subset`, read through the pseudo-labels.
    pub fn subset(self, subset: &Subset) -> Subset {
        let dataset = Mapped { inner: self.inner, map: Labels(self.labels) };
        Subset { dataset: Arc::new(dataset), indices: subset.indices.clone() }
    }
}

pub use pi3det_autolabel::quality::Quality as LabelQuality;

/// Precision / recall of the positive pseudo-labels (score ≥ `min_score`) against the frames'
/// ground truth `gt`, per class of `cfg` and IoU in `ious` (3D IoU, greedy by score, one GT per
/// label; [`pi3det_autolabel::quality`]). Both sides are limited to the BEV square `bev_range`
/// (`[x_min, y_min, x_max, y_max]`, LiDAR frame).
pub fn quality(
    labels: &[FrameDetections],
    gt: &[FrameInfo],
    cfg: &DetectorConfig,
    min_score: f64,
    ious: &[f64],
    bev_range: [f64; 4],
) -> Vec<LabelQuality> {
    let inside = |b: &Box3d| b.x >= bev_range[0] && b.x < bev_range[2] && b.y >= bev_range[1] && b.y < bev_range[3];
    let mut set = pi3det_autolabel::LabelSet::default();
    for f in labels {
        let kept =
            f.objects.iter().filter(|o| o.score.unwrap_or(1.0) >= min_score && inside(&o.box3d)).cloned().collect();
        set.frames.insert(f.info.id.clone(), kept);
    }
    let gt: Vec<FrameInfo> = gt
        .iter()
        .map(|g| FrameInfo { objects: g.objects.iter().filter(|o| inside(&o.box3d)).cloned().collect(), ..g.clone() })
        .collect();
    let classes: Vec<&str> = cfg.classes.iter().map(String::as_str).collect();
    let class_of = |n: &str| cfg.class_index(n).map(|k| cfg.classes[k].clone());
    pi3det_autolabel::quality::quality(&set, &gt, &classes, class_of, ious)
}

/// A markdown table of [`quality`] rows, one per (setting, class, IoU).
pub fn quality_table(rows: &[(String, Vec<LabelQuality>)]) -> String {
    pi3det_autolabel::quality::quality_table("pseudo-labels", rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(objects: Vec<Object>) -> FrameDetections {
        FrameDetections { info: FrameInfo::new("0", "x.bin".into()), objects }
    }

    fn scored(name: &str, b: Box3d, s: f64) -> Object {
        Object { score: Some(s), ..Object::new(name, b) }
    }

    #[test]
    fn precision_and_recall_by_hand() {
        let car = Box3d::new(10.0, 0.0, -1.0, 4.0, 2.0, 1.5, 0.0);
        let car2 = Box3d::new(20.0, 5.0, -1.0, 4.0, 2.0, 1.5, 0.0);
        let shifted = Box3d { x: 10.6, ..car }; // 3D IoU (3.4/4.6) ≈ 0.74
        let labels = vec![frame(vec![
            scored("Car", shifted, 0.9),
            scored("Car", Box3d { x: 30.0, ..car }, 0.8), // false positive
            scored("Car", car2, 0.3),                     // below the positive score
            scored("Pedestrian", Box3d::new(5.0, 5.0, -1.0, 0.6, 0.6, 1.7, 0.0), 0.9),
        ])];
        let mut gt = FrameInfo::new("0", "x.bin".into());
        gt.objects =
            vec![Object::new("Car", car), Object::new("Car", car2), Object::new("Car", Box3d { x: 90.0, ..car })];
        let cfg = DetectorConfig::default();
        let q = quality(&labels, &[gt], &cfg, 0.5, &[0.5, 0.7, 0.8], [-50.0, -50.0, 50.0, 50.0]);
        let car_q: Vec<&LabelQuality> = q.iter().filter(|q| q.class == "Car").collect();
        // Two positives, two GT in range (the one at x = 90 is outside); one match up to IoU 0.74.
        for q in &car_q[..2] {
            assert_eq!((q.labels, q.ground_truth, q.true_positives), (2, 2, 1), "{q:?}");
            assert!((q.precision - 0.5).abs() < 1e-12 && (q.recall - 0.5).abs() < 1e-12);
        }
        assert_eq!(car_q[2].true_positives, 0);
        let ped = q.iter().find(|q| q.class == "Pedestrian").unwrap();
        assert_eq!((ped.labels, ped.ground_truth, ped.precision), (1, 0, 0.0));
        assert!(quality_table(&[("with VPP".into(), q)]).contains("| with VPP | Car | 0.5 | 2 | 2 | 50.0 | 50.0 |"));
    }
}
