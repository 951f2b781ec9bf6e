//! Positive thresholds that follow the target (issue 47). A detector seeing a new platform is
//! less sure of everything, so a fixed `positive_score` can leave Knowledge-Adaptation with
//! almost no positives while the labeller still found many objects in the ignored band. When the
//! positives at `positive_score` fall below `min_positives_per_frame` on average, each class's
//! threshold drops to the `quantile` of that class's pseudo-label scores (the boxes at or above
//! the band's floor), never below `ignore_score + margin` and never above `positive_score`: the
//! ranking the labeller gives within the class is kept, only its calibration is not trusted,
//! and the ignored band keeps at least `margin` of width below every threshold.
//!
//! The chosen thresholds are applied by raising the scores of the boxes that pass them to
//! `positive_score` in the training labels ([`training_labels`]), so the preprocessor's single
//! ignore threshold treats them as positives; `pseudo_labels.jsonl` keeps the real scores.

use serde::{Deserialize, Serialize};

use crate::pseudo_labels::PseudoLabelConfig;
use pi3det_nn::config::DetectorConfig;
use pi3det_nn::detect::FrameDetections;
use pi3det_nn::error::{NnError, Result};

/// `[adaptive_thresholds]` of an adaptation config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptiveThresholdConfig {
    pub enabled: bool,
    /// Lower the thresholds when `positive_score` gives fewer positives than this per target
    /// frame on average.
    pub min_positives_per_frame: f64,
    /// Each class's threshold then: this quantile of its pseudo-label scores (0.5: the better
    /// half of the boxes the labeller kept become positives).
    pub quantile: f64,
    /// Thresholds stay at least this far above `ignore_score` (the ignored band's width).
    pub margin: f64,
}

impl Default for AdaptiveThresholdConfig {
    fn default() -> Self {
        Self { enabled: true, min_positives_per_frame: 1.0, quantile: 0.5, margin: 0.1 }
    }
}

impl AdaptiveThresholdConfig {
    pub fn validate(&self) -> Result<()> {
        let ok = self.min_positives_per_frame.is_finite()
            && self.min_positives_per_frame >= 0.0
            && (0.0..=1.0).contains(&self.quantile)
            && self.margin.is_finite()
            && self.margin >= 0.0;
        if ok {
            Ok(())
        } else {
            Err(NnError::config(
                "adaptive_thresholds",
                format!(
                "adaptive_thresholds: need min_positives_per_frame ≥ 0, quantile in [0, 1], margin ≥ 0 (got {self:?})"
            ),
            ))
        }
    }
}

/// One class's threshold and what it changed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassThreshold {
    pub class: String,
    pub threshold: f64,
    /// The class's boxes at or above the band's floor, its positives at `positive_score` and
    /// at `threshold`.
    pub boxes: usize,
    pub positives_fixed: usize,
    pub positives: usize,
}

/// The thresholds of one set of pseudo-labels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Thresholds {
    /// Whether any class's threshold was lowered below `positive_score`.
    pub lowered: bool,
    /// Positives per frame at `positive_score` (what triggered the choice).
    pub fixed_positives_per_frame: f64,
    pub classes: Vec<ClassThreshold>,
}

impl Thresholds {
    /// The threshold of a pseudo-label's class (`positive` for a class without one).
    pub fn of(&self, class: &str, positive: f64) -> f64 {
        self.classes.iter().find(|c| c.class == class).map_or(positive, |c| c.threshold)
    }

    /// One line for the log.
    pub fn summary(&self) -> String {
        let per: Vec<String> = self
            .classes
            .iter()
            .map(|c| format!("{} ≥ {:.3} ({} → {} positives)", c.class, c.threshold, c.positives_fixed, c.positives))
            .collect();
        per.join(", ")
    }
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    let k = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[k.min(sorted.len() - 1)]
}

/// The thresholds for `labels` (one entry per target frame, boxes at or above the band's
/// floor): `positive_score` for every class unless the positives per frame fall short of
/// `cfg.min_positives_per_frame`.
pub fn choose(
    labels: &[FrameDetections],
    det: &DetectorConfig,
    pl: &PseudoLabelConfig,
    cfg: &AdaptiveThresholdConfig,
) -> Thresholds {
    let frames = labels.len().max(1) as f64;
    let scores_of = |class: &str| -> Vec<f64> {
        let mut s: Vec<f64> = labels
            .iter()
            .flat_map(|f| &f.objects)
            .filter(|o| det.class_index(&o.name).is_some_and(|k| det.classes[k] == class))
            .filter_map(|o| o.score)
            .filter(|&s| s >= pl.ignore_score)
            .collect();
        s.sort_by(f64::total_cmp);
        s
    };
    let fixed: usize =
        labels.iter().flat_map(|f| &f.objects).filter(|o| o.score.unwrap_or(1.0) >= pl.positive_score).count();
    let fixed_per_frame = fixed as f64 / frames;
    let adapt = cfg.enabled && fixed_per_frame < cfg.min_positives_per_frame;
    let floor = (pl.ignore_score + cfg.margin).min(pl.positive_score);
    let classes = det
        .classes
        .iter()
        .map(|c| {
            let s = scores_of(c);
            let count = |t: f64| s.iter().filter(|&&v| v >= t).count();
            let threshold = if adapt && !s.is_empty() {
                quantile(&s, cfg.quantile).clamp(floor, pl.positive_score)
            } else {
                pl.positive_score
            };
            ClassThreshold {
                class: c.clone(),
                threshold,
                boxes: s.len(),
                positives_fixed: count(pl.positive_score),
                positives: count(threshold),
            }
        })
        .collect::<Vec<_>>();
    Thresholds {
        lowered: classes.iter().any(|c| c.threshold < pl.positive_score),
        fixed_positives_per_frame: fixed_per_frame,
        classes,
    }
}

/// The labels KA trains on: boxes at or above their class's threshold score at least
/// `positive_score` (positives for the preprocessor), the rest keep their score (ignored below
/// `positive_score`).
pub fn training_labels(
    labels: &[FrameDetections],
    th: &Thresholds,
    det: &DetectorConfig,
    positive_score: f64,
) -> Vec<FrameDetections> {
    labels
        .iter()
        .map(|f| {
            let objects = f
                .objects
                .iter()
                .map(|o| {
                    let mut o = o.clone();
                    let class = det.class_index(&o.name).map(|k| det.classes[k].as_str());
                    if let (Some(s), Some(c)) = (o.score, class) {
                        if s >= th.of(c, positive_score) && s < positive_score {
                            o.score = Some(positive_score);
                        }
                    }
                    o
                })
                .collect();
            FrameDetections { info: f.info.clone(), objects }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::{FrameInfo, Object};
    use pi3det_geometry::Box3d;

    fn frame(scores: &[(&str, f64)]) -> FrameDetections {
        let b = Box3d::new(0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0);
        FrameDetections {
            info: FrameInfo::new("0", "x.bin".into()),
            objects: scores.iter().map(|&(n, s)| Object { score: Some(s), ..Object::new(n, b) }).collect(),
        }
    }

    #[test]
    fn thresholds_fall_to_the_quantile_only_when_positives_are_scarce() {
        let det = DetectorConfig::default();
        let pl = PseudoLabelConfig { positive_score: 0.5, ignore_score: 0.2, refresh_every: 0 };
        let cfg = AdaptiveThresholdConfig::default();
        // Two frames, one positive: 0.5 per frame < 1.
        let labels = vec![
            frame(&[("Car", 0.45), ("Car", 0.35), ("Car", 0.25), ("Pedestrian", 0.22)]),
            frame(&[("Car", 0.6), ("Car", 0.41), ("Car", 0.21)]),
        ];
        let th = choose(&labels, &det, &pl, &cfg);
        assert!(th.lowered && (th.fixed_positives_per_frame - 0.5).abs() < 1e-12);
        // Car scores 0.21 0.25 0.35 0.41 0.45 0.6: the median (index round(2.5) = 3) is 0.41.
        let car = &th.classes[0];
        assert_eq!(
            (car.class.as_str(), car.threshold, car.boxes, car.positives_fixed, car.positives),
            ("Car", 0.41, 6, 1, 3)
        );
        // The pedestrian's only box (0.22) is below the floor 0.2 + 0.1: the floor.
        let ped = &th.classes[1];
        assert!((ped.threshold - 0.3).abs() < 1e-12 && ped.positives == 0, "{ped:?}");
        let train = training_labels(&labels, &th, &det, pl.positive_score);
        let scores: Vec<f64> = train[0].objects.iter().map(|o| o.score.unwrap()).collect();
        assert_eq!(scores, vec![0.5, 0.35, 0.25, 0.22]);
        assert_eq!(train[1].objects[0].score, Some(0.6), "higher scores stay");
        assert_eq!(train[1].objects[1].score, Some(0.5));

        // Plentiful positives, or the rule off: the fixed threshold.
        let many = vec![frame(&[("Car", 0.9), ("Car", 0.3)]), frame(&[("Car", 0.7)])];
        let th = choose(&many, &det, &pl, &cfg);
        assert!(!th.lowered && th.classes.iter().all(|c| c.threshold == 0.5));
        let off = AdaptiveThresholdConfig { enabled: false, ..cfg };
        assert!(!choose(&labels, &det, &pl, &off).lowered);
        assert_eq!(training_labels(&labels, &choose(&labels, &det, &pl, &off), &det, 0.5), labels);
    }
}
