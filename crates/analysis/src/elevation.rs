//! Point elevation relative to the sensor (paper Fig. 2, upper left): z of every point in a level
//! frame centred on the sensor, so a tilted drone or quadruped is compared with a vehicle on the
//! same footing. The level frame comes from the pose when there is one, else from the ground fit.

use nalgebra::UnitQuaternion;
use serde::Serialize;

use crate::error::AnalysisError;
use crate::histogram::Histogram;

/// Where the rotation that levels a frame came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, PartialOrd, Ord)]
#[serde(rename_all = "snake_case")]
pub enum LevelSource {
    Pose,
    Ground,
    /// Neither: the sensor frame is used as it is.
    Sensor,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ElevationStats {
    /// Point z in the level frame (sensor at 0), metres.
    pub z_level_m: Histogram,
    /// Points strictly above the sensor in the level frame (exact count).
    pub above_sensor: u64,
    /// Frames levelled by pose, by ground fit, or not at all.
    pub frames_by_pose: u64,
    pub frames_by_ground: u64,
    pub frames_unlevelled: u64,
}

impl ElevationStats {
    pub fn new(bins: usize) -> Self {
        // −40…+20 m: a drone at 20 m with 20° of tilt still sees most of its scan inside.
        Self {
            z_level_m: Histogram::new(-40.0, 20.0, 3 * bins),
            above_sensor: 0,
            frames_by_pose: 0,
            frames_by_ground: 0,
            frames_unlevelled: 0,
        }
    }

    /// One frame's points (LiDAR frame) and the rotation that levels them.
    pub fn add_frame<I>(&mut self, points: I, level_from_lidar: &UnitQuaternion<f64>, source: LevelSource)
    where
        I: IntoIterator<Item = [f64; 3]>,
    {
        match source {
            LevelSource::Pose => self.frames_by_pose += 1,
            LevelSource::Ground => self.frames_by_ground += 1,
            LevelSource::Sensor => self.frames_unlevelled += 1,
        }
        // Only the z row of the rotation is needed.
        let m = level_from_lidar.to_rotation_matrix();
        let row = [m[(2, 0)], m[(2, 1)], m[(2, 2)]];
        for p in points {
            let z = row[0] * p[0] + row[1] * p[1] + row[2] * p[2];
            self.z_level_m.add(z);
            if z > 0.0 {
                self.above_sensor += 1;
            }
        }
    }

    /// Share of the points above the sensor.
    pub fn share_above_sensor(&self) -> f64 {
        self.above_sensor as f64 / self.z_level_m.count().max(1) as f64
    }

    pub fn merge(&mut self, o: &ElevationStats) -> Result<(), AnalysisError> {
        self.z_level_m.merge(&o.z_level_m)?;
        self.above_sensor += o.above_sensor;
        self.frames_by_pose += o.frames_by_pose;
        self.frames_by_ground += o.frames_by_ground;
        self.frames_unlevelled += o.frames_unlevelled;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levelled_elevation_and_share_above() {
        // Sensor pitched 30° nose-down (positive pitch): a point straight ahead along the LiDAR x
        // axis at 10 m is really 5 m below the sensor.
        let pitch = 30f64.to_radians();
        let level = UnitQuaternion::from_euler_angles(0.0, pitch, 0.0);
        let mut e = ElevationStats::new(60);
        e.add_frame([[10.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 5.0, -2.0]], &level, LevelSource::Pose);
        assert!((e.z_level_m.moments.min + 5.0).abs() < 1e-9, "{:?}", e.z_level_m.moments);
        assert_eq!(e.above_sensor, 1);
        assert!((e.share_above_sensor() - 1.0 / 3.0).abs() < 1e-12);
        let mut raw = ElevationStats::new(60);
        raw.add_frame([[1.0, 2.0, -1.5], [1.0, 2.0, 0.5]], &UnitQuaternion::identity(), LevelSource::Sensor);
        assert_eq!(raw.z_level_m.moments.mean, -0.5);
        assert_eq!(raw.z_level_m.moments.variance(), 1.0);
        e.merge(&raw).unwrap();
        assert_eq!((e.frames_by_pose, e.frames_unlevelled, e.above_sensor), (1, 1, 2));
    }
}
