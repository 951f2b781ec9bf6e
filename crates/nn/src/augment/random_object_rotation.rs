//! Random object rotation (OpenPCDet `random_local_rotation`): each box and the points inside it
//! turn about the box's vertical axis by an angle from `range_rad`. Ignored boxes
//! ([`Sample::ignored`]) and their points stay as they are (box and points still agree): they
//! teach nothing, so turning them would gain nothing, and leaving them keeps the RNG draws, and
//! so the augmentation of a seed, what they were without pseudo-labels.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{points_in_box, Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RandomObjectRotationConfig {
    pub range_rad: [f64; 2],
}

impl Default for RandomObjectRotationConfig {
    fn default() -> Self {
        Self { range_rad: [-std::f64::consts::PI / 20.0, std::f64::consts::PI / 20.0] }
    }
}

pub struct RandomObjectRotation(pub RandomObjectRotationConfig);

impl Augment for RandomObjectRotation {
    fn name(&self) -> &'static str {
        "random_object_rotation"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        let [lo, hi] = self.0.range_rad;
        for k in 0..s.boxes.len() {
            let angle = if hi > lo { rng.random_range(lo..hi) } else { lo };
            let b = s.boxes[k];
            let (sn, c) = angle.sin_cos();
            for i in points_in_box(&s.points, &b) {
                let p = &mut s.points[i];
                let (x, y) = (p[0] as f64 - b.x, p[1] as f64 - b.y);
                p[0] = (b.x + c * x - sn * y) as f32;
                p[1] = (b.y + sn * x + c * y) as f32;
            }
            s.boxes[k].heading += angle;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn objects_turn_with_their_points() {
        let s0 = sample();
        let mut s = s0.clone();
        RandomObjectRotation(RandomObjectRotationConfig { range_rad: [0.2, 0.4] }).apply(&mut s, &mut rng(7));
        assert_points_follow_boxes(&s0, &s);
        for (a, b) in s.boxes.iter().zip(&s0.boxes) {
            assert!((0.2..0.4).contains(&(a.heading - b.heading)));
            assert_eq!((a.x, a.y, a.dx), (b.x, b.y, b.dx));
        }
        // Ground points outside the boxes did not move.
        assert_eq!(s.points[100..], s0.points[100..]);
    }
}
