//! Ego motion from poses (paper Fig. 2, lower left): roll, pitch and yaw of the sensor in the world,
//! and their frame-to-frame jitter along a sequence. Meaningful when the world frame is
//! gravity-aligned (simulator, nuScenes `ego2global`); poses relative to a sequence's first frame
//! (M3ED `Ln_T_L0`) carry that frame's tilt in every roll and pitch.

use pi3det_geometry::boxes::wrap_angle;
use pi3det_geometry::RollPitchYaw;
use serde::Serialize;

use crate::error::AnalysisError;
use crate::histogram::Histogram;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EgoMotionStats {
    pub roll_deg: Histogram,
    pub pitch_deg: Histogram,
    pub yaw_deg: Histogram,
    /// Change from the previous frame of the same sequence.
    pub roll_jitter_deg: Histogram,
    pub pitch_jitter_deg: Histogram,
    pub yaw_jitter_deg: Histogram,
}

impl EgoMotionStats {
    pub fn new(bins: usize) -> Self {
        Self {
            roll_deg: Histogram::new(-45.0, 45.0, bins),
            pitch_deg: Histogram::new(-45.0, 45.0, bins),
            yaw_deg: Histogram::new(-180.0, 180.0, bins),
            roll_jitter_deg: Histogram::new(-20.0, 20.0, bins),
            pitch_jitter_deg: Histogram::new(-20.0, 20.0, bins),
            yaw_jitter_deg: Histogram::new(-20.0, 20.0, bins),
        }
    }

    /// Frames with a pose.
    pub fn frames(&self) -> u64 {
        self.roll_deg.count() + self.roll_deg.non_finite
    }

    pub fn add_attitude(&mut self, rpy: &RollPitchYaw) {
        self.roll_deg.add(rpy.roll_rad.to_degrees());
        self.pitch_deg.add(rpy.pitch_rad.to_degrees());
        self.yaw_deg.add(wrap_angle(rpy.yaw_rad).to_degrees());
    }

    /// The step between two consecutive frames of a sequence.
    pub fn add_step(&mut self, previous: &RollPitchYaw, current: &RollPitchYaw) {
        let [dr, dp, dy] = attitude_step_deg(previous, current);
        self.roll_jitter_deg.add(dr);
        self.pitch_jitter_deg.add(dp);
        self.yaw_jitter_deg.add(dy);
    }

    pub fn merge(&mut self, o: &EgoMotionStats) -> Result<(), AnalysisError> {
        self.roll_deg.merge(&o.roll_deg)?;
        self.pitch_deg.merge(&o.pitch_deg)?;
        self.yaw_deg.merge(&o.yaw_deg)?;
        self.roll_jitter_deg.merge(&o.roll_jitter_deg)?;
        self.pitch_jitter_deg.merge(&o.pitch_jitter_deg)?;
        self.yaw_jitter_deg.merge(&o.yaw_jitter_deg)
    }
}

/// `current − previous` for roll, pitch and yaw in degrees, each wrapped to [−180°, 180°).
pub fn attitude_step_deg(previous: &RollPitchYaw, current: &RollPitchYaw) -> [f64; 3] {
    [
        wrap_angle(current.roll_rad - previous.roll_rad).to_degrees(),
        wrap_angle(current.pitch_rad - previous.pitch_rad).to_degrees(),
        wrap_angle(current.yaw_rad - previous.yaw_rad).to_degrees(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::{Pose, PoseExt};

    #[test]
    fn attitude_and_jitter_from_poses() {
        // Roll alternating ±5°, pitch constant 2°, yaw crossing ±180°.
        let poses: Vec<RollPitchYaw> = (0..4)
            .map(|k| {
                let roll = if k % 2 == 0 { 5f64 } else { -5f64 };
                let yaw = 179.0 + 1.0 * k as f64;
                Pose::from_xyz_rpy([k as f64, 0.0, 1.8], roll.to_radians(), 2f64.to_radians(), yaw.to_radians())
                    .roll_pitch_yaw()
            })
            .collect();
        let mut s = EgoMotionStats::new(90);
        poses.iter().for_each(|p| s.add_attitude(p));
        poses.windows(2).for_each(|w| s.add_step(&w[0], &w[1]));
        assert_eq!(s.frames(), 4);
        assert!(s.roll_deg.moments.mean.abs() < 1e-9 && (s.roll_deg.moments.std() - 5.0).abs() < 1e-9);
        assert!((s.pitch_deg.moments.mean - 2.0).abs() < 1e-9 && s.pitch_deg.moments.std() < 1e-9);
        // Δroll = −10°, +10°, −10°; yaw steps of +1° across the ±180° wrap.
        let j = &s.roll_jitter_deg.moments;
        assert!((j.min + 10.0).abs() < 1e-9 && (j.max - 10.0).abs() < 1e-9 && j.count == 3);
        assert!((s.yaw_jitter_deg.moments.mean - 1.0).abs() < 1e-9 && s.yaw_jitter_deg.moments.max < 1.0 + 1e-9);
    }
}
