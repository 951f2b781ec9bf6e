//! Targets seen from the sensor (paper Fig. 2, right): relative pitch θʳ from the sensor to each
//! box centre against the bird's-eye-view distance ρ. θʳ > 0: the target is above the sensor.

use nalgebra::{UnitQuaternion, Vector3};
use pi3det_geometry::Box3d;
use serde::Serialize;

use crate::error::AnalysisError;
use crate::histogram::{Histogram, Histogram2d};

/// BEV distance ρ (m) and relative pitch θʳ (rad) of a point seen from the sensor at the origin.
pub fn relative_pitch(center: [f64; 3]) -> (f64, f64) {
    let rho_m = center[0].hypot(center[1]);
    (rho_m, center[2].atan2(rho_m))
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetStats {
    /// ρ in metres (x) against θʳ in degrees (y), with θʳ moments per distance bin.
    pub pitch_by_distance: Histogram2d,
    pub relative_pitch_deg: Histogram,
    pub distance_m: Histogram,
}

impl TargetStats {
    pub fn new(bins: usize, bins_2d: usize) -> Self {
        Self {
            pitch_by_distance: Histogram2d::new((0.0, 100.0), bins_2d, (-90.0, 90.0), bins_2d),
            relative_pitch_deg: Histogram::new(-90.0, 90.0, bins),
            distance_m: Histogram::new(0.0, 100.0, bins),
        }
    }

    /// One box, its centre taken through `frame_from_lidar` first (identity: the sensor frame as
    /// the paper does; a levelling rotation: gravity-aligned view). Returns `(ρ m, θʳ deg)`.
    pub fn add_box(&mut self, b: &Box3d, frame_from_lidar: &UnitQuaternion<f64>) -> (f64, f64) {
        let c = frame_from_lidar * Vector3::new(b.x, b.y, b.z);
        let (rho_m, theta_rad) = relative_pitch([c.x, c.y, c.z]);
        let theta_deg = theta_rad.to_degrees();
        self.pitch_by_distance.add(rho_m, theta_deg);
        self.relative_pitch_deg.add(theta_deg);
        self.distance_m.add(rho_m);
        (rho_m, theta_deg)
    }

    pub fn merge(&mut self, o: &TargetStats) -> Result<(), AnalysisError> {
        self.pitch_by_distance.merge(&o.pitch_by_distance)?;
        self.relative_pitch_deg.merge(&o.relative_pitch_deg)?;
        self.distance_m.merge(&o.distance_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_pitch_known_answers() {
        let mut t = TargetStats::new(180, 10);
        let id = UnitQuaternion::identity();
        // Drone 10 m above a car 10 m ahead: 45° down. Quadruped 0.6 m up, pedestrian centre
        // 0.9 m up, 3 m ahead: atan(0.3/3) up.
        let (rho, theta) = t.add_box(&Box3d::new(6.0, 8.0, -10.0, 4.0, 2.0, 1.5, 0.0), &id);
        assert!((rho - 10.0).abs() < 1e-12 && (theta + 45.0).abs() < 1e-9);
        let (_, theta) = t.add_box(&Box3d::new(0.0, -3.0, 0.3, 0.6, 0.6, 1.8, 0.0), &id);
        assert!((theta - 0.1f64.atan().to_degrees()).abs() < 1e-9);
        assert_eq!(t.relative_pitch_deg.count(), 2);
        // 10 m columns: the pedestrian (3 m) in the first, the car (ρ = 10 m) in the second.
        assert_eq!(t.pitch_by_distance.columns[0].count, 1);
        assert!((t.pitch_by_distance.columns[1].mean + 45.0).abs() < 1e-9);
        // Levelled view: a sensor pitched 45° nose-down (positive pitch) sees a target on its x
        // axis 45° below the horizon.
        let level = UnitQuaternion::from_euler_angles(0.0, 45f64.to_radians(), 0.0);
        let (_, theta) = TargetStats::new(10, 10).add_box(&Box3d::new(10.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0), &level);
        assert!((theta + 45.0).abs() < 1e-9);
    }
}
