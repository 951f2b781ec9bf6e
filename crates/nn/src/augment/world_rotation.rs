//! Random world rotation about z (OpenPCDet `random_world_rotation`): points and box centres
//! rotated by an angle from `range_rad`, headings offset by it.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{rotate_z, Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldRotationConfig {
    pub range_rad: [f64; 2],
}

impl Default for WorldRotationConfig {
    fn default() -> Self {
        Self { range_rad: [-std::f64::consts::FRAC_PI_4, std::f64::consts::FRAC_PI_4] }
    }
}

pub struct WorldRotation(pub WorldRotationConfig);

impl WorldRotation {
    pub fn rotate(s: &mut Sample, angle: f64) {
        rotate_z(&mut s.points, angle);
        let (sn, c) = angle.sin_cos();
        for b in s.all_boxes_mut() {
            let (x, y) = (b.x, b.y);
            b.x = c * x - sn * y;
            b.y = sn * x + c * y;
            b.heading += angle;
        }
    }
}

impl Augment for WorldRotation {
    fn name(&self) -> &'static str {
        "world_rotation"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        let [lo, hi] = self.0.range_rad;
        let angle = if hi > lo { rng.random_range(lo..hi) } else { lo };
        Self::rotate(s, angle);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn rotates_points_and_boxes_together() {
        let s0 = sample();
        let mut s = s0.clone();
        WorldRotation(WorldRotationConfig::default()).apply(&mut s, &mut rng(3));
        assert_points_follow_boxes(&s0, &s);
        let d = s.boxes[0].heading - s0.boxes[0].heading;
        assert!(d.abs() <= std::f64::consts::FRAC_PI_4 && d != 0.0);
        // Distances from the origin are kept.
        assert!((s.boxes[0].x.hypot(s.boxes[0].y) - s0.boxes[0].x.hypot(s0.boxes[0].y)).abs() < 1e-9);
    }
}
