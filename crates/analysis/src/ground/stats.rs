//! Distributions of the ground estimates of a group of frames and, where the data has poses, of
//! their error against the pose (per frame and after temporal smoothing).

use pi3det_geometry::boxes::wrap_angle;
use pi3det_geometry::RollPitchYaw;
use serde::Serialize;

use super::smoothing::SmoothedAttitude;
use super::GroundEstimate;
use crate::error::AnalysisError;
use crate::histogram::Histogram;

/// Error histograms are fine-binned whatever `--bins` says: their median and 95th percentile are
/// headline numbers (0.01° bins up to 20°, larger errors fall in the overflow and still count).
const ABS_ERROR_BINS: usize = 2000;
const ABS_ERROR_MAX_DEG: f64 = 20.0;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroundStats {
    /// Frames where the fit was attempted, and where it found a ground plane.
    pub attempted: u64,
    pub found: u64,
    pub roll_deg: Histogram,
    pub pitch_deg: Histogram,
    /// 5 cm bins up to 40 m (a drone's altitude fits; a vehicle's ≈1.8 m is resolved).
    pub height_m: Histogram,
    pub inlier_ratio: Histogram,
    pub confidence: Histogram,
    /// Estimate minus pose, signed (frames with both).
    pub roll_error_deg: Histogram,
    pub pitch_error_deg: Histogram,
    pub abs_roll_error_deg: Histogram,
    pub abs_pitch_error_deg: Histogram,
    /// The same after temporal smoothing (sequences only).
    pub smoothed_abs_roll_error_deg: Histogram,
    pub smoothed_abs_pitch_error_deg: Histogram,
}

fn abs_error_histogram() -> Histogram {
    Histogram::new(0.0, ABS_ERROR_MAX_DEG, ABS_ERROR_BINS)
}

impl GroundStats {
    pub fn new(bins: usize) -> Self {
        Self {
            attempted: 0,
            found: 0,
            roll_deg: Histogram::new(-45.0, 45.0, bins),
            pitch_deg: Histogram::new(-45.0, 45.0, bins),
            height_m: Histogram::new(0.0, 40.0, 800),
            inlier_ratio: Histogram::new(0.0, 1.0 + 1e-9, bins),
            confidence: Histogram::new(0.0, 1.0 + 1e-9, bins),
            roll_error_deg: Histogram::new(-10.0, 10.0, 400),
            pitch_error_deg: Histogram::new(-10.0, 10.0, 400),
            abs_roll_error_deg: abs_error_histogram(),
            abs_pitch_error_deg: abs_error_histogram(),
            smoothed_abs_roll_error_deg: abs_error_histogram(),
            smoothed_abs_pitch_error_deg: abs_error_histogram(),
        }
    }

    /// One frame's estimate (`None`: no ground found) and its pose attitude when known.
    pub fn add(&mut self, estimate: Option<&GroundEstimate>, pose: Option<&RollPitchYaw>) {
        self.attempted += 1;
        let Some(e) = estimate else { return };
        self.found += 1;
        self.roll_deg.add(e.roll_rad.to_degrees());
        self.pitch_deg.add(e.pitch_rad.to_degrees());
        self.height_m.add(e.height_m);
        self.inlier_ratio.add(e.inlier_ratio);
        self.confidence.add(e.confidence);
        if let Some(p) = pose {
            let (dr, dp) = attitude_error_deg(e.roll_rad, e.pitch_rad, p);
            self.roll_error_deg.add(dr);
            self.pitch_error_deg.add(dp);
            self.abs_roll_error_deg.add(dr.abs());
            self.abs_pitch_error_deg.add(dp.abs());
        }
    }

    pub fn add_smoothed(&mut self, smoothed: &SmoothedAttitude, pose: &RollPitchYaw) {
        if smoothed.roll_rad.is_finite() {
            let (dr, dp) = attitude_error_deg(smoothed.roll_rad, smoothed.pitch_rad, pose);
            self.smoothed_abs_roll_error_deg.add(dr.abs());
            self.smoothed_abs_pitch_error_deg.add(dp.abs());
        }
    }

    pub fn merge(&mut self, o: &GroundStats) -> Result<(), AnalysisError> {
        self.attempted += o.attempted;
        self.found += o.found;
        for (a, b) in self.histograms_mut().into_iter().zip(o.histograms()) {
            a.merge(b)?;
        }
        Ok(())
    }

    fn histograms(&self) -> [&Histogram; 11] {
        [
            &self.roll_deg,
            &self.pitch_deg,
            &self.height_m,
            &self.inlier_ratio,
            &self.confidence,
            &self.roll_error_deg,
            &self.pitch_error_deg,
            &self.abs_roll_error_deg,
            &self.abs_pitch_error_deg,
            &self.smoothed_abs_roll_error_deg,
            &self.smoothed_abs_pitch_error_deg,
        ]
    }

    fn histograms_mut(&mut self) -> [&mut Histogram; 11] {
        [
            &mut self.roll_deg,
            &mut self.pitch_deg,
            &mut self.height_m,
            &mut self.inlier_ratio,
            &mut self.confidence,
            &mut self.roll_error_deg,
            &mut self.pitch_error_deg,
            &mut self.abs_roll_error_deg,
            &mut self.abs_pitch_error_deg,
            &mut self.smoothed_abs_roll_error_deg,
            &mut self.smoothed_abs_pitch_error_deg,
        ]
    }
}

/// Estimated minus true roll and pitch, in degrees, wrapped.
pub fn attitude_error_deg(roll_rad: f64, pitch_rad: f64, truth: &RollPitchYaw) -> (f64, f64) {
    (wrap_angle(roll_rad - truth.roll_rad).to_degrees(), wrap_angle(pitch_rad - truth.pitch_rad).to_degrees())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_against_pose() {
        let e = GroundEstimate {
            roll_rad: 0.1,
            pitch_rad: -0.05,
            height_m: 1.7,
            normal_lidar: [0.0, 0.0, 1.0],
            inliers: 10,
            candidates: 20,
            inlier_ratio: 0.5,
            rms_m: 0.0,
            spread_m: 1.0,
            confidence: 0.5,
            iterations: 1,
        };
        let truth =
            RollPitchYaw { roll_rad: 0.1 + 1f64.to_radians(), pitch_rad: -0.05 - 2f64.to_radians(), yaw_rad: 3.0 };
        let mut s = GroundStats::new(90);
        s.add(Some(&e), Some(&truth));
        s.add(None, Some(&truth));
        assert_eq!((s.attempted, s.found), (2, 1));
        assert!((s.roll_error_deg.moments.mean + 1.0).abs() < 1e-9);
        assert!((s.abs_pitch_error_deg.moments.mean - 2.0).abs() < 1e-9);
        assert!((s.abs_pitch_error_deg.quantile(0.5).unwrap() - 2.0).abs() < 1e-9);
        assert!((s.height_m.moments.mean - 1.7).abs() < 1e-12);
        let mut m = s.clone();
        m.merge(&s).unwrap();
        assert_eq!(m.found, 2);
    }
}
