//! Statistical Normalization (SN; Wang et al., "Train in Germany, Test in the USA", CVPR 2020):
//! source objects are resized by the difference between the target's and the source's mean
//! object size per class, and the points inside move with them (scaled in the box frame,
//! heights from the bottom, as [`super::random_object_scaling`]), so the detector learns the
//! target's sizes. SN assumes the target's mean sizes are known (from a few labels or
//! statistics); the benchmark takes them from the target's training labels.

use std::collections::BTreeMap;

use pi3det_geometry::Box3d;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::random_object_scaling::resize_object;
use super::{Augment, Sample};

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StatisticalNormalizationConfig {
    /// Per class name: `[Δdx, Δdy, Δdz]` in metres (target mean − source mean).
    pub size_delta_m: BTreeMap<String, [f64; 3]>,
}

impl StatisticalNormalizationConfig {
    /// Every delta is a finite number.
    pub fn is_valid(&self) -> bool {
        self.size_delta_m.values().flatten().all(|d| d.is_finite())
    }
}

/// SN with the deltas indexed by the detector's class indices.
pub struct StatisticalNormalization {
    delta: Vec<Option<[f64; 3]>>,
}

impl StatisticalNormalization {
    pub fn new(cfg: &StatisticalNormalizationConfig, class_names: &[String]) -> Self {
        Self { delta: class_names.iter().map(|c| cfg.size_delta_m.get(c).copied()).collect() }
    }
}

/// `b` resized by `d` with its bottom kept on the ground (sizes floored at 0.1 m).
pub fn shifted_box(b: &Box3d, d: [f64; 3]) -> Box3d {
    let (dx, dy, dz) = ((b.dx + d[0]).max(0.1), (b.dy + d[1]).max(0.1), (b.dz + d[2]).max(0.1));
    Box3d { dx, dy, dz, z: b.bottom() + 0.5 * dz, ..*b }
}

impl Augment for StatisticalNormalization {
    fn name(&self) -> &'static str {
        "statistical_normalization"
    }

    fn apply(&self, s: &mut Sample, _rng: &mut ChaCha8Rng) {
        for k in 0..s.boxes.len() {
            let Some(d) = self.delta.get(s.classes[k]).copied().flatten() else { continue };
            let b = s.boxes[k];
            let to = shifted_box(&b, d);
            resize_object(&mut s.points, &b, &to);
            s.boxes[k] = to;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::points_in_box;
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn sizes_shift_by_the_class_delta_and_points_follow() {
        let s0 = sample();
        let mut s = s0.clone();
        let names = vec!["Car".to_string(), "Pedestrian".to_string()];
        // The sample's first box is class 0 (Car), the second class 1.
        let cfg = StatisticalNormalizationConfig {
            size_delta_m: [("Car".to_string(), [-0.4, -0.2, -0.16])].into_iter().collect(),
        };
        StatisticalNormalization::new(&cfg, &names).apply(&mut s, &mut rng(0));
        let (a, b) = (s.boxes[0], s0.boxes[0]);
        assert!((a.dx - (b.dx - 0.4)).abs() < 1e-12 && (a.dy - (b.dy - 0.2)).abs() < 1e-12);
        assert!((a.dz - (b.dz - 0.16)).abs() < 1e-12 && (a.bottom() - b.bottom()).abs() < 1e-12);
        assert_eq!(s.boxes[1], s0.boxes[1], "a class without a delta is left alone");
        let old = points_in_box(&s0.points, &b);
        assert!(!old.is_empty());
        for &i in &old {
            assert!(a.contains([s.points[i][0] as f64, s.points[i][1] as f64, s.points[i][2] as f64]));
        }
        assert_eq!(s.points.len(), s0.points.len());
    }
}
