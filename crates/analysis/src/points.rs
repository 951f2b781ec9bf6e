//! Point distributions (appendix Tables 9–11): x, y, z and intensity of every point in the sensor
//! frame, and points per frame.

use pi3det_data::PointCloud;
use serde::Serialize;

use crate::error::AnalysisError;
use crate::histogram::Histogram;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointStats {
    pub x_m: Histogram,
    pub y_m: Histogram,
    pub z_m: Histogram,
    /// Normalised to [0, 1] (nuScenes' 0–255 is divided by 255).
    pub intensity: Histogram,
    pub points_per_frame: Histogram,
}

impl PointStats {
    pub fn new(bins: usize) -> Self {
        Self {
            x_m: Histogram::new(-120.0, 120.0, 2 * bins),
            y_m: Histogram::new(-120.0, 120.0, 2 * bins),
            z_m: Histogram::new(-40.0, 20.0, 2 * bins),
            intensity: Histogram::new(0.0, 1.0 + 1e-9, bins),
            points_per_frame: Histogram::new(0.0, 300_000.0, bins),
        }
    }

    /// Every point of a cloud; intensity multiplied by `intensity_scale`.
    pub fn add_cloud(&mut self, cloud: &PointCloud, intensity_scale: f64) {
        self.points_per_frame.add(cloud.len() as f64);
        let has_intensity = cloud.stride() > 3;
        for p in cloud.iter() {
            self.x_m.add(p[0] as f64);
            self.y_m.add(p[1] as f64);
            self.z_m.add(p[2] as f64);
            if has_intensity {
                self.intensity.add(p[3] as f64 * intensity_scale);
            }
        }
    }

    pub fn merge(&mut self, o: &PointStats) -> Result<(), AnalysisError> {
        self.x_m.merge(&o.x_m)?;
        self.y_m.merge(&o.y_m)?;
        self.z_m.merge(&o.z_m)?;
        self.intensity.merge(&o.intensity)?;
        self.points_per_frame.merge(&o.points_per_frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coordinates_and_scaled_intensity() {
        let cloud = PointCloud::from_xyzi(&[[1.0, -2.0, -1.5, 51.0], [3.0, 2.0, 0.5, 255.0]]);
        let mut s = PointStats::new(50);
        s.add_cloud(&cloud, 1.0 / 255.0);
        assert_eq!(s.x_m.moments.mean, 2.0);
        assert_eq!(s.y_m.moments.variance(), 4.0);
        assert_eq!(s.z_m.moments.mean, -0.5);
        assert!((s.intensity.moments.mean - 0.6).abs() < 1e-6);
        assert_eq!(s.intensity.overflow, 0);
        assert_eq!(s.points_per_frame.moments.mean, 2.0);
    }
}
