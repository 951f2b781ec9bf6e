//! The three cross-platform discrepancies of Pi3DET §3.3 / Fig. 2, measured on frames:
//! ego-motion (roll/pitch spread), point elevation relative to the sensor in a level frame, and
//! the relative pitch of targets seen from the sensor. Works on any frames with a pose
//! (simulated or read back from disk).

use pi3det_data::Frame;
use pi3det_geometry::{level_from_sensor, PoseExt};
use serde::Serialize;

/// Summary statistics of one platform's frames.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiscrepancyStats {
    pub frames: usize,
    pub roll_std_deg: f64,
    pub pitch_std_deg: f64,
    pub roll_max_abs_deg: f64,
    pub pitch_max_abs_deg: f64,
    /// Median and quartiles of point z relative to the sensor, after undoing roll and pitch.
    pub elevation_median_m: f64,
    pub elevation_q25_m: f64,
    pub elevation_q75_m: f64,
    /// Share of points above the sensor (level frame).
    pub share_above_sensor: f64,
    pub boxes: usize,
    /// Relative pitch of box centres seen from the sensor, `atan2(z, ρ)` in the sensor frame as
    /// stored (negative: below).
    pub relative_pitch_median_deg: f64,
    pub relative_pitch_std_deg: f64,
    pub bev_distance_median_m: f64,
}

/// Collects frames one at a time; keeps every `point_stride`-th point for the elevation quantiles.
#[derive(Debug, Clone)]
pub struct StatsAccumulator {
    point_stride: usize,
    rolls: Vec<f64>,
    pitches: Vec<f64>,
    elevations: Vec<f32>,
    rel_pitch: Vec<f64>,
    bev_dist: Vec<f64>,
}

impl Default for StatsAccumulator {
    fn default() -> Self {
        Self::new(7)
    }
}

impl StatsAccumulator {
    pub fn new(point_stride: usize) -> Self {
        Self {
            point_stride: point_stride.max(1),
            rolls: vec![],
            pitches: vec![],
            elevations: vec![],
            rel_pitch: vec![],
            bev_dist: vec![],
        }
    }

    /// Adds a frame. Frames without a pose contribute points as they are (assumed level) and no
    /// attitude sample.
    pub fn add(&mut self, frame: &Frame) {
        let level = frame.info.world_from_lidar.map(|p| {
            let rpy = p.roll_pitch_yaw();
            self.rolls.push(rpy.roll_rad.to_degrees());
            self.pitches.push(rpy.pitch_rad.to_degrees());
            level_from_sensor(rpy)
        });
        for p in frame.points.xyz_f64().step_by(self.point_stride) {
            let v = nalgebra::Vector3::new(p[0], p[1], p[2]);
            let z = level.map_or(v.z, |q| (q * v).z);
            self.elevations.push(z as f32);
        }
        for o in &frame.info.objects {
            let rho = o.box3d.x.hypot(o.box3d.y);
            self.rel_pitch.push(o.box3d.z.atan2(rho).to_degrees());
            self.bev_dist.push(rho);
        }
    }

    pub fn finish(&self) -> DiscrepancyStats {
        let mut elev: Vec<f64> = self.elevations.iter().map(|v| f64::from(*v)).collect();
        let above =
            if elev.is_empty() { 0.0 } else { elev.iter().filter(|z| **z > 0.0).count() as f64 / elev.len() as f64 };
        let mut rel = self.rel_pitch.clone();
        let mut dist = self.bev_dist.clone();
        DiscrepancyStats {
            frames: self.rolls.len(),
            roll_std_deg: std_dev(&self.rolls),
            pitch_std_deg: std_dev(&self.pitches),
            roll_max_abs_deg: self.rolls.iter().fold(0.0, |m: f64, v| m.max(v.abs())),
            pitch_max_abs_deg: self.pitches.iter().fold(0.0, |m: f64, v| m.max(v.abs())),
            elevation_median_m: quantile(&mut elev, 0.5),
            elevation_q25_m: quantile(&mut elev, 0.25),
            elevation_q75_m: quantile(&mut elev, 0.75),
            share_above_sensor: above,
            boxes: rel.len(),
            relative_pitch_median_deg: quantile(&mut rel, 0.5),
            relative_pitch_std_deg: std_dev(&self.rel_pitch),
            bev_distance_median_m: quantile(&mut dist, 0.5),
        }
    }
}

fn std_dev(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// Nearest-rank quantile (NaN for no data); reorders `v`.
fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let k = ((v.len() - 1) as f64 * q).round() as usize;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::{FrameInfo, Object, PointCloud};
    use pi3det_geometry::{Box3d, Pose};

    #[test]
    fn level_frame_undoes_pitch() {
        // A sensor pitched 10° nose down sees a point straight ahead at the sensor's height with
        // a positive sensor-frame z; levelled, it is at z = 0.
        let pitch = 10f64.to_radians();
        let pose = Pose::from_xyz_rpy([0.0, 0.0, 5.0], 0.0, pitch, 0.0);
        let world_pt = nalgebra::Point3::new(10.0, 0.0, 5.0);
        let p = pose.inverse().transform_point(&world_pt);
        let mut info = FrameInfo::new("0", "x.bin".into());
        info.world_from_lidar = Some(pose);
        info.objects.push(Object::new("Car", Box3d::new(10.0, 0.0, -10.0, 4.0, 2.0, 1.5, 0.0)));
        let frame = Frame { info, points: PointCloud::from_xyzi(&[[p.x as f32, p.y as f32, p.z as f32, 0.5]]) };
        let mut acc = StatsAccumulator::new(1);
        acc.add(&frame);
        let s = acc.finish();
        assert!(p.z > 1.0);
        assert!(s.elevation_median_m.abs() < 1e-5, "{s:?}");
        assert!((s.relative_pitch_median_deg + 45.0).abs() < 1e-9);
    }
}
