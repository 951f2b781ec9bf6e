//! Random world scaling (OpenPCDet `random_world_scaling`): points, box centres and sizes scaled
//! by a factor from `range`.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldScalingConfig {
    pub range: [f64; 2],
}

impl Default for WorldScalingConfig {
    fn default() -> Self {
        Self { range: [0.95, 1.05] }
    }
}

pub struct WorldScaling(pub WorldScalingConfig);

impl WorldScaling {
    pub fn scale(s: &mut Sample, f: f64) {
        let ff = f as f32;
        for p in &mut s.points {
            p[0] *= ff;
            p[1] *= ff;
            p[2] *= ff;
        }
        for b in s.all_boxes_mut() {
            b.x *= f;
            b.y *= f;
            b.z *= f;
            b.dx *= f;
            b.dy *= f;
            b.dz *= f;
        }
        s.sensor_z *= f;
    }
}

impl Augment for WorldScaling {
    fn name(&self) -> &'static str {
        "world_scaling"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        let [lo, hi] = self.0.range;
        let f = if hi > lo { rng.random_range(lo..hi) } else { lo };
        Self::scale(s, f);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn scales_points_and_boxes_together() {
        let s0 = sample();
        let mut s = s0.clone();
        WorldScaling(WorldScalingConfig { range: [1.1, 1.2] }).apply(&mut s, &mut rng(5));
        assert_points_follow_boxes(&s0, &s);
        let f = s.boxes[0].dx / s0.boxes[0].dx;
        assert!((1.1..1.2).contains(&f));
        assert!((s.boxes[1].y / s0.boxes[1].y - f).abs() < 1e-12);
    }
}
