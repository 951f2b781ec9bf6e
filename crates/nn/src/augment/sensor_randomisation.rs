//! Sensor randomisation (issue 44's domain randomisation at training time): real sensors differ
//! in how they scale intensity (KITTI's reflectance averages about four times nuScenes' 8-bit
//! intensity over 255), some recordings lose it altogether, and they return fewer points than the
//! simulator's. Per frame: intensity multiplied by a factor from `intensity_scale` (clamped to
//! [0, 1]); with probability `intensity_lost`, every point's intensity replaced by the frame's
//! mean (what inference feeds a frame whose intensity was lost, from the training mean); and a
//! share of the points from `point_dropout` removed at random.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorRandomisationConfig {
    /// Range of the per-frame intensity factor.
    pub intensity_scale: [f64; 2],
    /// Probability that a frame's intensity is replaced by its mean.
    pub intensity_lost: f64,
    /// Range of the share of points dropped per frame.
    pub point_dropout: [f64; 2],
}

impl Default for SensorRandomisationConfig {
    fn default() -> Self {
        Self { intensity_scale: [0.3, 1.5], intensity_lost: 0.2, point_dropout: [0.0, 0.3] }
    }
}

impl SensorRandomisationConfig {
    pub fn is_valid(&self) -> bool {
        let range = |r: &[f64; 2]| r[0].is_finite() && r[1].is_finite() && 0.0 <= r[0] && r[0] <= r[1];
        range(&self.intensity_scale)
            && range(&self.point_dropout)
            && self.point_dropout[1] < 1.0
            && (0.0..=1.0).contains(&self.intensity_lost)
    }
}

pub struct SensorRandomisation(pub SensorRandomisationConfig);

fn draw(rng: &mut ChaCha8Rng, r: [f64; 2]) -> f64 {
    if r[1] > r[0] {
        rng.random_range(r[0]..r[1])
    } else {
        r[0]
    }
}

impl Augment for SensorRandomisation {
    fn name(&self) -> &'static str {
        "sensor_randomisation"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        let c = &self.0;
        let drop = draw(rng, c.point_dropout);
        if drop > 0.0 {
            s.points.retain(|_| rng.random::<f64>() >= drop);
        }
        if s.points.is_empty() {
            return;
        }
        if rng.random::<f64>() < c.intensity_lost {
            let mean = s.points.iter().map(|p| f64::from(p[3])).sum::<f64>() / s.points.len() as f64;
            s.points.iter_mut().for_each(|p| p[3] = mean as f32);
        } else {
            let f = draw(rng, c.intensity_scale) as f32;
            s.points.iter_mut().for_each(|p| p[3] = (p[3] * f).clamp(0.0, 1.0));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn scales_loses_and_drops_within_its_ranges() {
        let s0 = sample();
        let lost = SensorRandomisation(SensorRandomisationConfig {
            intensity_lost: 1.0,
            point_dropout: [0.0, 0.0],
            ..Default::default()
        });
        let mut s = s0.clone();
        lost.apply(&mut s, &mut rng(1));
        assert_eq!(s.points.len(), s0.points.len());
        assert!(s.points.iter().all(|p| p[3] == s.points[0][3]));
        let scaled = SensorRandomisation(SensorRandomisationConfig {
            intensity_scale: [2.0, 2.0],
            intensity_lost: 0.0,
            point_dropout: [0.5, 0.5],
        });
        let mut s = s0.clone();
        scaled.apply(&mut s, &mut rng(2));
        let kept = s.points.len() as f64 / s0.points.len() as f64;
        assert!((0.3..0.7).contains(&kept), "{kept}");
        assert!(s.points.iter().all(|p| (0.0..=1.0).contains(&p[3])));
        // Geometry and boxes are untouched.
        assert_eq!(s.boxes, s0.boxes);
        assert!(s.points.iter().all(|p| s0.points.iter().any(|q| q[..3] == p[..3])));
        assert!(!SensorRandomisationConfig { point_dropout: [0.0, 1.0], ..Default::default() }.is_valid());
    }
}
