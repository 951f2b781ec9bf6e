//! Virtual Platform Pose (Pi3DET-Net §4.1, paper Eq. 2): each target frame is seen from a virtual
//! sensor that has the target's yaw and planar position but no roll or pitch, at the source
//! platform's height above the ground. Points and boxes move together
//! (`virtual_from_lidar = T̄·T⁻¹`); detections made in the virtual frame go back through its
//! inverse ([`crate::preprocess::to_lidar`]), so evaluation and output stay in the sensor frame.
//!
//! Roll and pitch come from the frame's pose when the data has one (Euler 'xyz', as the public
//! code takes them), otherwise from the ground plane of the scan itself ([`pi3det_ground`]): the
//! released Pi3DET layout has no poses. The height above the ground always comes from the ground
//! fit (with a pose, the fit is constrained to the pose's attitude): a pose's z is measured from
//! the world origin, not from the ground under the platform. A frame where no ground is found
//! keeps the detector's plain transform (its `shift_z`) and is counted ([`VppCounts`]).
//!
//! In the detector's frame the source ground sits at `shift_z − source_height_m` (≈ 0 for the
//! CPU presets); a levelled target frame is lifted by its own estimated height to put its ground
//! at the same level, which is what "set the sensor height to the source platform's" means for
//! the network's input.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use nalgebra::Translation3;
use pi3det_data::Frame;
use pi3det_geometry::{level_from_sensor, Pose, PoseExt, RollPitchYaw};
use pi3det_ground::{estimate_ground, AttitudePrior, GroundConfig};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::data_loader::Subset;
use crate::error::{NnError, Result};
use crate::preprocess::FrameTransform;

/// Where a frame's roll and pitch come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AttitudeSource {
    /// The pose when the frame has one, else the ground plane.
    #[default]
    Auto,
    /// Always the ground plane (pose-free, as on the released Pi3DET layout).
    Ground,
}

/// Virtual Platform Pose settings (`[vpp]` of an adaptation config).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VppConfig {
    pub attitude: AttitudeSource,
    /// The source platform's sensor height above the ground; `None`: the median ground-fit height
    /// of up to `source_frames` source frames.
    pub source_height_m: Option<f64>,
    pub source_frames: usize,
    /// With a pose, the ground fit may deviate this much from the pose's attitude (the local
    /// ground is not exactly level).
    pub pose_tilt_tolerance_deg: f64,
}

impl Default for VppConfig {
    fn default() -> Self {
        Self { attitude: AttitudeSource::Auto, source_height_m: None, source_frames: 64, pose_tilt_tolerance_deg: 4.0 }
    }
}

impl VppConfig {
    pub fn validate(&self) -> Result<()> {
        let h_ok = self.source_height_m.is_none_or(|h| h.is_finite() && h > 0.0);
        let t_ok = self.pose_tilt_tolerance_deg.is_finite() && (0.0..45.0).contains(&self.pose_tilt_tolerance_deg);
        if h_ok && t_ok && self.source_frames > 0 {
            Ok(())
        } else {
            Err(NnError::config("vpp", format!("vpp: invalid settings {self:?}")))
        }
    }
}

/// How the frames seen so far were levelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct VppCounts {
    pub frames: usize,
    /// Roll and pitch from the pose.
    pub from_pose: usize,
    /// Roll and pitch from the ground plane.
    pub from_ground: usize,
    /// No ground found: the plain transform was kept.
    pub no_ground: usize,
}

/// The transform into the virtual frame, one per target frame (cached by point file).
pub struct VirtualPlatformPose {
    cfg: VppConfig,
    shift_z: f64,
    source_height_m: f64,
    ground: GroundConfig,
    cache: Mutex<HashMap<std::path::PathBuf, Pose>>,
    frames: AtomicUsize,
    from_pose: AtomicUsize,
    from_ground: AtomicUsize,
    no_ground: AtomicUsize,
}

impl VirtualPlatformPose {
    /// `shift_z`: the detector's z shift (its plain transform); `source_height_m`: the source
    /// sensor's height above its ground.
    pub fn new(cfg: &VppConfig, shift_z: f64, source_height_m: f64) -> Self {
        Self {
            cfg: cfg.clone(),
            shift_z,
            source_height_m,
            ground: GroundConfig::default(),
            cache: Mutex::new(HashMap::new()),
            frames: AtomicUsize::new(0),
            from_pose: AtomicUsize::new(0),
            from_ground: AtomicUsize::new(0),
            no_ground: AtomicUsize::new(0),
        }
    }

    pub fn source_height_m(&self) -> f64 {
        self.source_height_m
    }

    /// Frames levelled so far, by how (each distinct frame counted once).
    pub fn counts(&self) -> VppCounts {
        VppCounts {
            frames: self.frames.load(Ordering::Relaxed),
            from_pose: self.from_pose.load(Ordering::Relaxed),
            from_ground: self.from_ground.load(Ordering::Relaxed),
            no_ground: self.no_ground.load(Ordering::Relaxed),
        }
    }

    /// `virtual_from_lidar` of a frame, uncached and uncounted; `None` when no ground is found.
    pub fn virtual_from_lidar(&self, frame: &Frame) -> Option<(Pose, bool)> {
        let pose_rp = match (self.cfg.attitude, frame.info.world_from_lidar) {
            (AttitudeSource::Auto, Some(p)) => Some(p.roll_pitch_yaw()),
            _ => None,
        };
        let mut ground = self.ground;
        if let Some(rp) = pose_rp {
            ground.prior = AttitudePrior {
                roll_rad: rp.roll_rad,
                pitch_rad: rp.pitch_rad,
                max_tilt_rad: self.cfg.pose_tilt_tolerance_deg.to_radians(),
                ..ground.prior
            };
        }
        let est = estimate_ground(frame.points.xyz_f64(), &ground).ok()?;
        let (roll_rad, pitch_rad) = match pose_rp {
            Some(rp) => (rp.roll_rad, rp.pitch_rad),
            None => (est.roll_rad, est.pitch_rad),
        };
        let level = level_from_sensor(RollPitchYaw { roll_rad, pitch_rad, yaw_rad: 0.0 });
        let dz = self.shift_z - self.source_height_m + est.height_m;
        Some((Pose::from_parts(Translation3::new(0.0, 0.0, dz), level), pose_rp.is_some()))
    }
}

impl FrameTransform for VirtualPlatformPose {
    fn detector_from_lidar(&self, frame: &Frame) -> Pose {
        let key = frame.info.points_path.clone();
        if let Some(p) = self.cache.lock().ok().and_then(|c| c.get(&key).copied()) {
            return p;
        }
        let (pose, counter) = match self.virtual_from_lidar(frame) {
            Some((p, true)) => (p, &self.from_pose),
            Some((p, false)) => (p, &self.from_ground),
            None => (Pose::translation(0.0, 0.0, self.shift_z), &self.no_ground),
        };
        if let Ok(mut c) = self.cache.lock() {
            if c.insert(key, pose).is_none() {
                self.frames.fetch_add(1, Ordering::Relaxed);
                counter.fetch_add(1, Ordering::Relaxed);
            }
        }
        pose
    }
}

/// The median sensor height above the ground over up to `max_frames` frames spread over
/// `subset`, with the number of frames where ground was found.
pub fn median_sensor_height(subset: &Subset, max_frames: usize) -> Result<(f64, usize)> {
    let part = subset.clone().take_spread(max_frames);
    let cfg = GroundConfig::default();
    let heights: Vec<Option<f64>> = part
        .indices
        .par_iter()
        .map(|&i| {
            let f = part.dataset.load(i)?;
            Ok(estimate_ground(f.points.xyz_f64(), &cfg).ok().map(|e| e.height_m))
        })
        .collect::<Result<_>>()?;
    let mut h: Vec<f64> = heights.into_iter().flatten().collect();
    if h.is_empty() {
        return Err(NnError::Input(format!(
            "no ground found in any of {} source frames: set vpp.source_height_m",
            part.len()
        )));
    }
    h.sort_by(f64::total_cmp);
    Ok((h[h.len() / 2], h.len()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::{FrameInfo, Object, PointCloud};
    use pi3det_geometry::Box3d;

    use crate::config::DetectorConfig;
    use crate::preprocess::{frame_to_sample, to_lidar};

    /// A flat ground 12 m below a sensor tilted by roll 6°, pitch −9°, seen in the sensor frame,
    /// with a car standing on it.
    fn tilted_frame(with_pose: bool) -> (Frame, Box3d) {
        let (roll, pitch, height) = (6f64.to_radians(), -9f64.to_radians(), 12.0);
        let world_from_lidar = Pose::from_xyz_rpy([5.0, -3.0, height + 40.0], roll, pitch, 0.8);
        let lidar_from_world = world_from_lidar.inverse();
        let mut pts = Vec::new();
        for i in -40..=40 {
            for j in -40..=40 {
                let w = nalgebra::Point3::new(5.0 + i as f64, -3.0 + j as f64, 40.0);
                let p = lidar_from_world * w;
                pts.push([p.x as f32, p.y as f32, p.z as f32, 0.3]);
            }
        }
        let car_w = Box3d::new(15.0, 2.0, 40.8, 4.5, 1.9, 1.6, 0.3);
        let car = car_w.transformed(&lidar_from_world);
        let mut info = FrameInfo::new("0", "tilted.bin".into());
        info.objects.push(Object::new("Car", car));
        if with_pose {
            info.world_from_lidar = Some(world_from_lidar);
        }
        (Frame { info, points: PointCloud::from_xyzi(&pts) }, car)
    }

    fn check_levelled(with_pose: bool) {
        let (frame, car) = tilted_frame(with_pose);
        let vpp = VirtualPlatformPose::new(&VppConfig::default(), 1.9, 1.8);
        let pose = vpp.detector_from_lidar(&frame);
        let counts = vpp.counts();
        assert_eq!((counts.from_pose, counts.from_ground), if with_pose { (1, 0) } else { (0, 1) });
        let s = frame_to_sample(&frame, &DetectorConfig::default(), &pose, 0, None);
        // The ground is level at the source's ground height shift_z − source_height = 0.1 m.
        let zs: Vec<f32> = s.points.iter().map(|p| p[2]).collect();
        let (lo, hi) = zs.iter().fold((f32::MAX, f32::MIN), |(a, b), &z| (a.min(z), b.max(z)));
        assert!((lo - 0.1).abs() < 0.03 && (hi - 0.1).abs() < 0.03, "ground z in [{lo}, {hi}]");
        // The car stands on it (its centre half its height above), upright.
        let b = s.boxes[0];
        assert!((b.z - (0.1 + 0.8)).abs() < 0.03, "{b:?}");
        // Detections go back onto the label exactly (centre and size; heading to 1e-3).
        let back = to_lidar(&b, &pose);
        for (j, (x, y)) in back.to_array().iter().zip(car.to_array()).enumerate() {
            assert!((x - y).abs() < if j == 6 { 2e-2 } else { 1e-6 }, "{back:?} vs {car:?}");
        }
        // Cached: a second call returns the same pose and counts nothing new.
        assert_eq!(vpp.detector_from_lidar(&frame), pose);
        assert_eq!(vpp.counts().frames, 1);
    }

    #[test]
    fn levels_a_tilted_ground_with_a_pose() {
        check_levelled(true);
    }

    #[test]
    fn levels_a_tilted_ground_without_a_pose() {
        check_levelled(false);
    }

    #[test]
    fn a_frame_without_ground_keeps_the_plain_shift_and_is_counted() {
        let mut info = FrameInfo::new("0", "empty.bin".into());
        info.objects.push(Object::new("Car", Box3d::new(10.0, 0.0, -1.0, 4.0, 2.0, 1.5, 0.0)));
        let frame = Frame { info, points: PointCloud::from_xyzi(&[[1.0, 2.0, 3.0, 0.0]]) };
        let vpp = VirtualPlatformPose::new(&VppConfig::default(), 1.9, 1.8);
        assert_eq!(vpp.detector_from_lidar(&frame), Pose::translation(0.0, 0.0, 1.9));
        assert_eq!(vpp.counts(), VppCounts { frames: 1, from_pose: 0, from_ground: 0, no_ground: 1 });
    }
}
