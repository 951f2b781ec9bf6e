//! Frames → network inputs and training targets, without the network (shared with the loader
//! thread): the per-frame rigid transform into the detector's frame (`detector_from_lidar`),
//! class mapping, pillarization, the dense head's target assignment and batch collation.

pub mod vpp;

use std::sync::Arc;

use pi3det_data::Frame;
use pi3det_geometry::{Box3d, Pose};
use tch::Tensor;

use crate::augment::Sample;
use crate::config::DetectorConfig;
use crate::dense_heads::{AnyAssigner, BatchTargets, FrameTargets};
use crate::error::Result;
use crate::pillarize::{Grid, Pillarizer, Pillars, POINT_FEATURES, VOXEL_FEATURES};
use crate::target_assigner::center::CenterMap;

/// Where a frame goes before the network sees it: `detector_from_lidar` per frame. The config's
/// `shift_z` (OpenPCDet `SHIFT_COOR`) is the simplest case; Pi3DET-Net's Virtual Platform Pose
/// levels each frame by its own attitude.
pub trait FrameTransform: Send + Sync {
    fn detector_from_lidar(&self, frame: &Frame) -> Pose;
}

/// The same shift up the z axis for every frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShiftZ(pub f64);

impl FrameTransform for ShiftZ {
    fn detector_from_lidar(&self, _frame: &Frame) -> Pose {
        Pose::translation(0.0, 0.0, self.0)
    }
}

/// How inference brings a frame to the height the detector was trained at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Level {
    /// Level each frame from its own ground to the sensor height recorded in the checkpoint
    /// ([`crate::config::TrainedOn`]); the config's `shift_z` alone when none was recorded.
    Trained,
    /// Level each frame to this sensor height (m).
    Height(f64),
    /// The config's `shift_z` only (the frame as it is).
    Off,
}

impl Level {
    /// The sensor height frames are levelled to under `cfg`, if any.
    pub fn height_m(self, cfg: &DetectorConfig) -> Option<f64> {
        match self {
            Level::Trained => cfg.trained_on.and_then(|t| t.sensor_height_m),
            Level::Height(h) => Some(h),
            Level::Off => None,
        }
    }

    /// The Virtual Platform Pose levelling frames to [`Level::height_m`] (none when this does not
    /// level); its counts say how many frames had no ground.
    pub fn transform(self, cfg: &DetectorConfig) -> Result<Option<Arc<vpp::VirtualPlatformPose>>> {
        let Some(h) = self.height_m(cfg) else { return Ok(None) };
        let v = vpp::VppConfig { source_height_m: Some(h), ..Default::default() };
        v.validate()?;
        Ok(Some(Arc::new(vpp::VirtualPlatformPose::new(&v, cfg.shift_z, h))))
    }

    /// One line saying what this does under `cfg`, for the log.
    pub fn describe(self, cfg: &DetectorConfig) -> String {
        match (self, self.height_m(cfg)) {
            (Level::Off, _) => format!("frames not levelled (z shift {} m)", cfg.shift_z),
            (Level::Trained, None) => format!(
                "the checkpoint records no training sensor height: frames not levelled (z shift {} m; --vpp-height M levels them)",
                cfg.shift_z
            ),
            (Level::Trained, Some(h)) => format!(
                "each frame levelled from its ground to the training sensor height {h:.2} m (--no-level: as it is)"
            ),
            (Level::Height(_), Some(h)) => format!("each frame levelled from its ground to {h:.2} m"),
            (Level::Height(_), None) => unreachable!("a height always levels"),
        }
    }
}

/// Network input of a batch: pillars (or voxels) of all frames.
pub struct Inputs {
    /// `[ΣP, M, 10]` decorated points (voxels: `[ΣV, 1, 4]` point means).
    pub features: Tensor,
    /// `[ΣP]` flat index `b·nz·ny·nx + cell` (pillars: nz = 1).
    pub cells: Tensor,
    pub batch_size: i64,
}

impl Inputs {
    pub fn to_device(&self, d: tch::Device) -> Self {
        Self { features: self.features.to_device(d), cells: self.cells.to_device(d), batch_size: self.batch_size }
    }
}

/// Everything needed to turn frames into network inputs and targets.
pub struct Preprocessor {
    pub cfg: DetectorConfig,
    pub grid: Grid,
    /// Geometry of the dense head's output map.
    pub map: CenterMap,
    assigner: Box<dyn AnyAssigner>,
    transform: Arc<dyn FrameTransform>,
    /// Scored objects (pseudo-labels) below this score are ignored, not boxes ([`frame_to_sample`]).
    ignore_score_below: Option<f64>,
}

impl Preprocessor {
    pub fn new(cfg: &DetectorConfig) -> Result<Self> {
        cfg.validate()?;
        let grid = Grid::new(&cfg.pillars)?;
        let s = cfg.map_stride() as usize;
        let map = CenterMap {
            h: grid.ny / s,
            w: grid.nx / s,
            cell: [grid.vx * s as f64, grid.vy * s as f64],
            origin: [grid.x_min, grid.y_min],
        };
        let assigner = cfg.head.assigner(&map, cfg.classes.len());
        Ok(Self {
            cfg: cfg.clone(),
            grid,
            map,
            assigner,
            transform: Arc::new(ShiftZ(cfg.shift_z)),
            ignore_score_below: None,
        })
    }

    /// Uses `transform` for every frame instead of the config's z shift.
    pub fn with_frame_transform(mut self, transform: Arc<dyn FrameTransform>) -> Self {
        self.transform = transform;
        self
    }

    /// The same preprocessing (frame transform, ignored scores) for the config with inference
    /// precision `precision`.
    pub fn with_precision(&self, precision: crate::precision::Precision) -> Result<Self> {
        let mut cfg = self.cfg.clone();
        cfg.precision = precision;
        let mut p = Self::new(&cfg)?.with_frame_transform(self.transform.clone());
        p.ignore_score_below = self.ignore_score_below;
        Ok(p)
    }

    /// Self-training: objects with a score (pseudo-labels) below `threshold` become ignored boxes
    /// of their class ([`Sample::ignored`]) instead of training targets; objects without a score
    /// (ground truth) or scoring at least `threshold` stay boxes. Pseudo-labels below the low
    /// threshold of the band are expected to be dropped before (they are not in the frame). A NaN
    /// threshold ignores nothing.
    pub fn with_ignore_score_below(mut self, threshold: f64) -> Self {
        self.ignore_score_below = Some(threshold);
        self
    }

    /// The score below which objects are ignored, when set.
    pub fn ignore_score_below(&self) -> Option<f64> {
        self.ignore_score_below
    }

    pub fn pillarizer(&self) -> Result<Pillarizer> {
        Pillarizer::new(&self.cfg.pillars)
    }

    /// The frame in the detector's frame with its detectable boxes (those with at least
    /// `min_points` points; 0 keeps all) and its ignored ones (see
    /// [`Preprocessor::with_ignore_score_below`]).
    pub fn sample(&self, frame: &Frame, min_points: usize) -> Sample {
        let pose = self.transform.detector_from_lidar(frame);
        frame_to_sample(frame, &self.cfg, &pose, min_points, self.ignore_score_below)
    }

    /// Training targets of a sample (boxes in the detector's frame; its ignored boxes are left
    /// out of the losses).
    pub fn targets(&self, s: &Sample) -> FrameTargets {
        self.assigner.assign(&s.boxes, &s.classes, &s.ignored, &s.ignored_classes)
    }

    /// Stacks frames' targets.
    pub fn collate_targets(&self, targets: &[&FrameTargets]) -> Result<BatchTargets> {
        self.assigner.collate(targets)
    }

    /// Stacks frames' pillars into network inputs.
    pub fn collate_inputs(&self, pillars: &[&Pillars]) -> Inputs {
        let (m, f) = if self.grid.is_voxel() {
            (1, VOXEL_FEATURES)
        } else {
            (self.cfg.pillars.max_points_per_pillar, POINT_FEATURES)
        };
        let total: usize = pillars.iter().map(|p| p.len()).sum();
        let mut cells = Vec::with_capacity(total);
        let plane = (self.grid.nx * self.grid.ny * self.grid.nz) as i64;
        for (b, p) in pillars.iter().enumerate() {
            cells.extend(p.cells.iter().map(|&c| c + b as i64 * plane));
        }
        // The frames' features go straight into the tensor's memory (one copy).
        let features = Tensor::empty([total as i64, m as i64, f as i64], (tch::Kind::Float, tch::Device::Cpu));
        let n = total * m * f;
        if n > 0 {
            // SAFETY: a fresh, contiguous CPU float tensor of exactly `n` elements, not shared.
            let dst = unsafe { std::slice::from_raw_parts_mut(features.data_ptr() as *mut f32, n) };
            let mut at = 0;
            for p in pillars {
                dst[at..at + p.features.len()].copy_from_slice(&p.features);
                at += p.features.len();
            }
        }
        Inputs { features, cells: Tensor::from_slice(&cells), batch_size: pillars.len() as i64 }
    }
}

/// A frame whose points all have one intensity carries none (a converter lost it, a driver left
/// it out): the network, which learnt from real intensities, gets the training frames' mean
/// instead of an arbitrary constant such as the 1.0 Argoverse's converter writes.
pub fn impute_lost_intensity(points: &mut [[f32; 4]], mean: f32) -> bool {
    let Some(first) = points.first().map(|p| p[3]) else { return false };
    if points.len() < 2 || points.iter().any(|p| p[3] != first) {
        return false;
    }
    for p in points.iter_mut() {
        p[3] = mean;
    }
    true
}

/// A frame moved into the detector's frame by `detector_from_lidar`, with the boxes of the
/// detector's classes (at least `min_points` points; 0 keeps all). Non-finite points and
/// degenerate boxes are left out. With `ignore_score_below`, objects scoring below it go to
/// [`Sample::ignored`] whatever their point count (an ignored box only removes anchors from the
/// loss, so a sparse one does no harm); objects without a score are always boxes.
pub fn frame_to_sample(
    frame: &Frame,
    cfg: &DetectorConfig,
    detector_from_lidar: &Pose,
    min_points: usize,
    ignore_score_below: Option<f64>,
) -> Sample {
    let rot = detector_from_lidar.rotation.to_rotation_matrix();
    let m = rot.matrix();
    let t = detector_from_lidar.translation.vector;
    // The common case (a pure shift) skips the rotation.
    let pure_shift = (m - nalgebra::Matrix3::identity()).abs().max() < 1e-12;
    let r: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)] as f32));
    let tf = [t.x as f32, t.y as f32, t.z as f32];
    let mut points: Vec<[f32; 4]> = Vec::with_capacity(frame.points.len());
    for p in frame.points.iter() {
        let (x, y, z) = (p[0], p[1], p[2]);
        let q = if pure_shift {
            [x + tf[0], y + tf[1], z + tf[2], p.get(3).copied().unwrap_or(0.0)]
        } else {
            [
                r[0][0] * x + r[0][1] * y + r[0][2] * z + tf[0],
                r[1][0] * x + r[1][1] * y + r[1][2] * z + tf[1],
                r[2][0] * x + r[2][1] * y + r[2][2] * z + tf[2],
                p.get(3).copied().unwrap_or(0.0),
            ]
        };
        if q.iter().all(|v| v.is_finite()) {
            points.push(q);
        }
    }
    if let Some(mean) = cfg.trained_on.and_then(|t| t.intensity_mean) {
        impute_lost_intensity(&mut points, mean as f32);
    }
    let mut boxes = Vec::new();
    let mut classes = Vec::new();
    let (mut ignored, mut ignored_classes) = (Vec::new(), Vec::new());
    for o in &frame.info.objects {
        let Some(k) = cfg.class_index(&o.name) else { continue };
        let b = o.box3d;
        if !b.to_array().iter().all(|v| v.is_finite()) || b.dx <= 0.0 || b.dy <= 0.0 || b.dz <= 0.0 {
            continue;
        }
        if let (Some(s), Some(t)) = (o.score, ignore_score_below) {
            if s < t {
                ignored.push(b.transformed(detector_from_lidar));
                ignored_classes.push(k);
                continue;
            }
        }
        if min_points > 0 {
            let n = match o.num_points {
                Some(n) => n as usize,
                None => b.count_points(frame.points.xyz_f64()),
            };
            if n < min_points {
                continue;
            }
        }
        boxes.push(b.transformed(detector_from_lidar));
        classes.push(k);
    }
    Sample {
        points,
        boxes,
        classes,
        ignored,
        ignored_classes,
        platform_jitter: None,
        sensor_z: t.z,
        detector_from_lidar: *detector_from_lidar,
        world_from_lidar: frame.info.world_from_lidar,
    }
}

/// Boxes of a detection back into the LiDAR frame.
pub fn to_lidar(b: &Box3d, detector_from_lidar: &Pose) -> Box3d {
    b.transformed(&detector_from_lidar.inverse()).with_wrapped_heading()
}

#[cfg(test)]
mod tests {
    #[test]
    fn only_a_constant_intensity_is_replaced() {
        let mut lost = vec![[0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 1.0]];
        assert!(impute_lost_intensity(&mut lost, 0.3));
        assert!(lost.iter().all(|p| p[3] == 0.3));
        let mut real = vec![[0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.5]];
        assert!(!impute_lost_intensity(&mut real, 0.3));
        assert_eq!(real[1][3], 0.5);
    }

    use super::*;
    use pi3det_data::{FrameInfo, Object, PointCloud};

    /// A frame moved by a rotation and a translation: points and boxes move together (points
    /// inside each box stay inside), and detections map back onto the original labels.
    #[test]
    fn detector_from_lidar_moves_points_and_boxes_and_back() {
        let car = Box3d::new(12.0, -3.0, -0.9, 4.5, 1.9, 1.6, 0.4);
        let mut info = FrameInfo::new("0", "x.bin".into());
        info.objects.push(Object::new("Car", car));
        let pts: Vec<[f32; 4]> = (0..40)
            .map(|k| {
                let t = k as f64 / 40.0 - 0.5;
                let (s, c) = car.heading.sin_cos();
                let (lx, ly) = (t * 4.0, 0.3 * (k % 3) as f64 - 0.3);
                [(car.x + c * lx - s * ly) as f32, (car.y + s * lx + c * ly) as f32, (car.z + 0.5 * t) as f32, 0.5]
            })
            .collect();
        let frame = Frame { info, points: PointCloud::from_xyzi(&pts) };
        let cfg = DetectorConfig::default();
        let pose = Pose::from_parts(
            nalgebra::Translation3::new(2.0, -1.0, 1.8),
            nalgebra::UnitQuaternion::from_euler_angles(0.02, -0.03, 0.7),
        );
        let s = frame_to_sample(&frame, &cfg, &pose, 1, None);
        assert_eq!(s.boxes.len(), 1);
        assert_eq!(s.detector_from_lidar, pose);
        let inside = s.points.iter().filter(|p| s.boxes[0].contains([p[0] as f64, p[1] as f64, p[2] as f64])).count();
        assert!(inside >= 36, "{inside} of 40 points inside the moved box");
        // Boxes stay upright, so a tilt changes the heading by the yaw of the tilted x axis and
        // the way back by a slightly different one (here 2e-4 rad); centre and sizes are exact.
        let back = to_lidar(&s.boxes[0], &pose);
        for (j, (a, b)) in back.to_array().iter().zip(car.to_array()).enumerate() {
            assert!((a - b).abs() < if j == 6 { 1e-3 } else { 1e-6 }, "{back:?} vs {car:?}");
        }
        // The plain shift is the config's default.
        let shifted = frame_to_sample(&frame, &cfg, &ShiftZ(1.9).detector_from_lidar(&frame), 0, None);
        assert!((shifted.boxes[0].z - (car.z + 1.9)).abs() < 1e-9 && shifted.sensor_z == 1.9);
    }

    /// Pseudo-labels below the threshold become ignored boxes of their class (whatever their
    /// points); ground truth (no score) and confident pseudo-labels stay boxes; unknown classes
    /// are dropped either way; without a threshold nothing changes.
    #[test]
    fn scored_objects_below_the_threshold_are_ignored() {
        let car = Box3d::new(12.0, -3.0, -0.9, 4.5, 1.9, 1.6, 0.4);
        let ped = Box3d::new(6.0, 2.0, -0.8, 0.7, 0.6, 1.7, 0.0);
        let obj = |name: &str, b: Box3d, score: Option<f64>, points: u32| Object {
            score,
            num_points: Some(points),
            ..Object::new(name, b)
        };
        let mut info = FrameInfo::new("0", "x.bin".into());
        info.objects = vec![
            obj("Car", car, None, 30),                              // GT
            obj("Car", Box3d { x: 20.0, ..car }, Some(0.8), 30),    // confident
            obj("Pedestrian", ped, Some(0.4), 0),                   // ignored, no points
            obj("Car", Box3d { y: 5.0, ..car }, Some(0.3), 30),     // ignored
            obj("Car", Box3d { x: 30.0, ..car }, Some(0.6), 30),    // at the threshold: kept
            obj("Cyclist", Box3d { x: 8.0, ..ped }, Some(0.1), 30), // not a detector class
            obj("Car", Box3d { x: 40.0, ..car }, Some(0.9), 0),     // too few points
        ];
        let frame = Frame { info, points: PointCloud::from_xyzi(&[]) };
        let cfg = DetectorConfig::default();
        let shift = Pose::translation(0.0, 0.0, 1.5);
        let s = frame_to_sample(&frame, &cfg, &shift, 5, Some(0.6));
        assert_eq!(s.boxes.iter().map(|b| b.x).collect::<Vec<_>>(), vec![12.0, 20.0, 30.0]);
        assert_eq!(s.classes, vec![0, 0, 0]);
        assert_eq!(s.ignored, vec![Box3d { z: ped.z + 1.5, ..ped }, Box3d { y: 5.0, z: car.z + 1.5, ..car }]);
        assert_eq!(s.ignored_classes, vec![1, 0]);
        // No threshold: every scored object is a box as before.
        let plain = frame_to_sample(&frame, &cfg, &shift, 5, None);
        assert_eq!(plain.boxes.len(), 4);
        assert!(plain.ignored.is_empty() && plain.ignored_classes.is_empty());
        // The same through the preprocessor (with its config's shift_z).
        let prep = Preprocessor::new(&cfg).unwrap().with_ignore_score_below(0.6);
        assert_eq!(prep.ignore_score_below(), Some(0.6));
        let s = prep.sample(&frame, 5);
        assert_eq!((s.boxes.len(), s.ignored.len()), (3, 2));
        let plain = Preprocessor::new(&cfg).unwrap().sample(&frame, 5);
        assert_eq!((plain.boxes.len(), plain.ignored.len()), (4, 0));
    }
}
