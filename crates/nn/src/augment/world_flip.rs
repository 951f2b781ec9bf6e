//! Random world flip (OpenPCDet `random_world_flip`): mirror the scene across the x axis
//! (`y → −y`, heading → −heading) and/or across the y axis (`x → −x`, heading → π − heading),
//! each with probability `probability`.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldFlipConfig {
    /// Flip along x (negate y).
    pub along_x: bool,
    /// Flip along y (negate x). Off by default: a forward-facing sensor's scene is not
    /// front/back symmetric (OpenPCDet's KITTI configs flip along x only).
    pub along_y: bool,
    pub probability: f64,
}

impl Default for WorldFlipConfig {
    fn default() -> Self {
        Self { along_x: true, along_y: false, probability: 0.5 }
    }
}

pub struct WorldFlip(pub WorldFlipConfig);

impl WorldFlip {
    pub fn flip_x_axis(s: &mut Sample) {
        for p in &mut s.points {
            p[1] = -p[1];
        }
        for b in s.all_boxes_mut() {
            b.y = -b.y;
            b.heading = -b.heading;
        }
    }

    pub fn flip_y_axis(s: &mut Sample) {
        for p in &mut s.points {
            p[0] = -p[0];
        }
        for b in s.all_boxes_mut() {
            b.x = -b.x;
            b.heading = std::f64::consts::PI - b.heading;
        }
    }
}

impl Augment for WorldFlip {
    fn name(&self) -> &'static str {
        "world_flip"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        if self.0.along_x && rng.random_bool(self.0.probability) {
            Self::flip_x_axis(s);
        }
        if self.0.along_y && rng.random_bool(self.0.probability) {
            Self::flip_y_axis(s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn flips_points_and_boxes_together() {
        let s0 = sample();
        let mut s = s0.clone();
        WorldFlip::flip_x_axis(&mut s);
        assert_points_follow_boxes(&s0, &s);
        assert_eq!(s.boxes[0].heading, -0.3);
        let mut t = s0.clone();
        WorldFlip::flip_y_axis(&mut t);
        assert_points_follow_boxes(&s0, &t);
        // Flipping twice is the identity; probability 0 changes nothing.
        WorldFlip::flip_x_axis(&mut s);
        assert_eq!(s, s0);
        let mut u = s0.clone();
        WorldFlip(WorldFlipConfig { along_x: true, along_y: true, probability: 0.0 }).apply(&mut u, &mut rng(1));
        assert_eq!(u, s0);
    }
}
