//! ST3D's curriculum data augmentation (§3.3): the half-widths of the object- and world-level
//! augmentations around their identity grow by `factor` at each milestone epoch, compounding
//! (×1.1 at epochs 5, 10, 20, 25 in ST3D), so self-training sees progressively harder samples.

use serde::{Deserialize, Serialize};

use pi3det_nn::augment::AugmentConfig;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CurriculumConfig {
    pub milestones: Vec<usize>,
    pub factor: f64,
}

impl Default for CurriculumConfig {
    fn default() -> Self {
        Self { milestones: vec![5, 10, 20, 25], factor: 1.1 }
    }
}

impl CurriculumConfig {
    /// The half-width multiplier in `epoch` (0-based): `factor` to the milestones passed.
    pub fn multiplier(&self, epoch: usize) -> f64 {
        let passed = self.milestones.iter().filter(|&&m| epoch >= m).count();
        self.factor.powi(passed as i32)
    }

    /// `augments` with their ranges widened for `epoch`: rotations about 0, scalings about 1.
    pub fn apply(&self, augments: &[AugmentConfig], epoch: usize) -> Vec<AugmentConfig> {
        let k = self.multiplier(epoch);
        let widen = |r: [f64; 2], centre: f64| [centre + (r[0] - centre) * k, centre + (r[1] - centre) * k];
        augments
            .iter()
            .map(|a| match a {
                AugmentConfig::WorldRotation(c) => {
                    AugmentConfig::WorldRotation(pi3det_nn::augment::WorldRotationConfig {
                        range_rad: widen(c.range_rad, 0.0),
                    })
                }
                AugmentConfig::WorldScaling(c) => {
                    AugmentConfig::WorldScaling(pi3det_nn::augment::WorldScalingConfig { range: widen(c.range, 1.0) })
                }
                AugmentConfig::RandomObjectRotation(c) => {
                    AugmentConfig::RandomObjectRotation(pi3det_nn::augment::RandomObjectRotationConfig {
                        range_rad: widen(c.range_rad, 0.0),
                    })
                }
                AugmentConfig::RandomObjectScaling(c) => {
                    AugmentConfig::RandomObjectScaling(pi3det_nn::augment::RandomObjectScalingConfig {
                        range: widen(c.range, 1.0),
                        ..c.clone()
                    })
                }
                other => other.clone(),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_nn::augment::{WorldRotationConfig, WorldScalingConfig};

    #[test]
    fn half_widths_compound_at_milestones() {
        let c = CurriculumConfig::default();
        let m: Vec<f64> = [0, 4, 5, 9, 10, 19, 20, 25, 40].iter().map(|&e| c.multiplier(e)).collect();
        let want = [1.0, 1.0, 1.1, 1.1, 1.21, 1.21, 1.331, 1.4641, 1.4641];
        for (a, b) in m.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{m:?}");
        }
        let augs = vec![
            AugmentConfig::WorldRotation(WorldRotationConfig { range_rad: [-0.5, 0.5] }),
            AugmentConfig::WorldScaling(WorldScalingConfig { range: [0.95, 1.05] }),
        ];
        let at10 = c.apply(&augs, 10);
        let AugmentConfig::WorldRotation(r) = &at10[0] else { panic!() };
        assert!((r.range_rad[0] + 0.605).abs() < 1e-12 && (r.range_rad[1] - 0.605).abs() < 1e-12);
        let AugmentConfig::WorldScaling(s) = &at10[1] else { panic!() };
        assert!((s.range[0] - (1.0 - 0.05 * 1.21)).abs() < 1e-12 && (s.range[1] - (1.0 + 0.05 * 1.21)).abs() < 1e-12);
        assert_eq!(c.apply(&augs, 0), augs);
    }
}
