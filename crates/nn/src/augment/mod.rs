//! Training augmentations: each a named, configurable transform of a [`Sample`]'s points and boxes
//! (OpenPCDet `data_augmentor`, plus Pi3DET's Random Platform Jitter). They run on the loader
//! thread, in the order the config lists them, with a per-frame seeded RNG (reproducible whatever
//! the thread count).

pub mod gt_sampling;
pub mod random_object_rotation;
pub mod random_object_scaling;
pub mod random_platform_jitter;
pub mod sensor_randomisation;
pub mod statistical_normalization;
pub mod world_flip;
pub mod world_rotation;
pub mod world_scaling;

use std::sync::Arc;

use pi3det_geometry::{Box3d, Pose};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use gt_sampling::{GtDatabase, GtSampling, GtSamplingConfig};
pub use random_object_rotation::{RandomObjectRotation, RandomObjectRotationConfig};
pub use random_object_scaling::{RandomObjectScaling, RandomObjectScalingConfig};
pub use random_platform_jitter::{RandomPlatformJitter, RandomPlatformJitterConfig};
pub use sensor_randomisation::{SensorRandomisation, SensorRandomisationConfig};
pub use statistical_normalization::{StatisticalNormalization, StatisticalNormalizationConfig};
pub use world_flip::{WorldFlip, WorldFlipConfig};
pub use world_rotation::{WorldRotation, WorldRotationConfig};
pub use world_scaling::{WorldScaling, WorldScalingConfig};

use crate::error::{NnError, Result};

/// A training frame: points (x, y, z, intensity), boxes and their class indices.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sample {
    pub points: Vec<[f32; 4]>,
    pub boxes: Vec<Box3d>,
    pub classes: Vec<usize>,
    /// Boxes that teach nothing (self-training pseudo-labels of middling score) and their class
    /// indices: anchors, heatmap cells and RoIs on them are left out of the losses of their class.
    /// Scene-moving augmentations move them with `boxes` ([`Sample::all_boxes_mut`]).
    pub ignored: Vec<Box3d>,
    pub ignored_classes: Vec<usize>,
    /// Roll and pitch (rad) Random Platform Jitter applied, for a rotation-regression loss.
    pub platform_jitter: Option<[f64; 2]>,
    /// Height of the LiDAR origin in this sample's frame (the config's `shift_z`): the platform
    /// rotates about its sensor, not about the shifted origin.
    pub sensor_z: f64,
    /// The transform the loader applied to the frame (before any augmentation): detections made
    /// in this frame go back to the LiDAR frame through its inverse.
    pub detector_from_lidar: Pose,
    /// The frame's pose, when the data has one.
    pub world_from_lidar: Option<Pose>,
}

impl Sample {
    /// The regular and the ignored boxes: what a transform of the whole scene moves.
    pub fn all_boxes_mut(&mut self) -> impl Iterator<Item = &mut Box3d> {
        self.boxes.iter_mut().chain(self.ignored.iter_mut())
    }
}

/// One augmentation.
pub trait Augment: Send + Sync {
    fn name(&self) -> &'static str;
    fn apply(&self, sample: &mut Sample, rng: &mut ChaCha8Rng);
}

/// The configurable augmentations (`[[train.augment]]` tables with a `type`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum AugmentConfig {
    GtSampling(GtSamplingConfig),
    RandomObjectRotation(RandomObjectRotationConfig),
    WorldFlip(WorldFlipConfig),
    WorldRotation(WorldRotationConfig),
    WorldScaling(WorldScalingConfig),
    RandomPlatformJitter(RandomPlatformJitterConfig),
    RandomObjectScaling(RandomObjectScalingConfig),
    StatisticalNormalization(StatisticalNormalizationConfig),
    SensorRandomisation(SensorRandomisationConfig),
}

impl AugmentConfig {
    pub fn name(&self) -> &'static str {
        match self {
            Self::GtSampling(_) => "gt_sampling",
            Self::RandomObjectRotation(_) => "random_object_rotation",
            Self::WorldFlip(_) => "world_flip",
            Self::WorldRotation(_) => "world_rotation",
            Self::WorldScaling(_) => "world_scaling",
            Self::RandomPlatformJitter(_) => "random_platform_jitter",
            Self::RandomObjectScaling(_) => "random_object_scaling",
            Self::StatisticalNormalization(_) => "statistical_normalization",
            Self::SensorRandomisation(_) => "sensor_randomisation",
        }
    }

    pub fn validate(&self) -> Result<()> {
        let range_ok = |r: &[f64; 2]| r[0].is_finite() && r[1].is_finite() && r[0] <= r[1];
        let ok = match self {
            Self::GtSampling(c) => {
                c.sample.iter().all(|s| s.count <= 1000)
                    && c.ground_margin_m.is_finite()
                    && c.ground_margin_m > 0.0
                    && (0.0..=1.0).contains(&c.ground_quantile)
            }
            Self::RandomObjectRotation(c) => range_ok(&c.range_rad),
            Self::WorldFlip(c) => (0.0..=1.0).contains(&c.probability),
            Self::WorldRotation(c) => range_ok(&c.range_rad),
            Self::WorldScaling(c) => range_ok(&c.range) && c.range[0] > 0.0,
            Self::RandomPlatformJitter(c) => c.max_deg.is_finite() && (0.0..90.0).contains(&c.max_deg),
            Self::RandomObjectScaling(c) => range_ok(&c.range) && c.range[0] > 0.0 && c.max_tries > 0,
            Self::StatisticalNormalization(c) => c.is_valid(),
            Self::SensorRandomisation(c) => c.is_valid(),
        };
        if ok {
            Ok(())
        } else {
            Err(NnError::config("train.augment", format!("augmentation {}: invalid parameters {self:?}", self.name())))
        }
    }

    /// Builds the transform; ground-truth sampling needs the database built from the training set
    /// and the detector's class names (`class_names[k]` names class `k`).
    pub fn build(&self, database: Option<&Arc<GtDatabase>>, class_names: &[String]) -> Result<Box<dyn Augment>> {
        Ok(match self {
            Self::GtSampling(c) => {
                let db = database.ok_or_else(|| {
                    NnError::config("train.augment.gt_sampling", "gt_sampling needs a ground-truth database")
                })?;
                Box::new(GtSampling::new(c.clone(), db.clone()).with_classes(class_names))
            }
            Self::RandomObjectRotation(c) => Box::new(RandomObjectRotation(c.clone())),
            Self::WorldFlip(c) => Box::new(WorldFlip(c.clone())),
            Self::WorldRotation(c) => Box::new(WorldRotation(c.clone())),
            Self::WorldScaling(c) => Box::new(WorldScaling(c.clone())),
            Self::RandomPlatformJitter(c) => Box::new(RandomPlatformJitter(c.clone())),
            Self::RandomObjectScaling(c) => Box::new(RandomObjectScaling(c.clone())),
            Self::StatisticalNormalization(c) => Box::new(StatisticalNormalization::new(c, class_names)),
            Self::SensorRandomisation(c) => Box::new(SensorRandomisation(c.clone())),
        })
    }
}

/// OpenPCDet's PointPillars pipeline: GT sampling, flip, rotation ±45°, scaling ±5% (no Random
/// Object Scaling: the Pi3DET appendix found it hurts; Random Platform Jitter is for Pi3DET-Net's
/// pre-adaptation and off here).
pub fn default_pipeline() -> Vec<AugmentConfig> {
    vec![
        AugmentConfig::GtSampling(GtSamplingConfig::default()),
        AugmentConfig::WorldFlip(WorldFlipConfig::default()),
        AugmentConfig::WorldRotation(WorldRotationConfig::default()),
        AugmentConfig::WorldScaling(WorldScalingConfig::default()),
    ]
}

/// Rotates points about z (in place), as OpenPCDet's `rotate_points_along_z`.
pub(crate) fn rotate_z(points: &mut [[f32; 4]], angle: f64) {
    let (s, c) = angle.sin_cos();
    let (s, c) = (s as f32, c as f32);
    for p in points {
        let (x, y) = (p[0], p[1]);
        p[0] = c * x - s * y;
        p[1] = s * x + c * y;
    }
}

/// Indices of points inside a box (inclusive test, f64).
pub(crate) fn points_in_box(points: &[[f32; 4]], b: &Box3d) -> Vec<usize> {
    let r2 = 0.25 * (b.dx * b.dx + b.dy * b.dy) + 1e-9;
    let (lo, hi) = (b.bottom(), b.top());
    points
        .iter()
        .enumerate()
        .filter(|(_, p)| {
            let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
            let (ex, ey) = (x - b.x, y - b.y);
            z >= lo && z <= hi && ex * ex + ey * ey <= r2 && b.contains([x, y, z])
        })
        .map(|(i, _)| i)
        .collect()
}

#[cfg(test)]
pub(crate) mod test_util {
    use super::*;
    use rand::SeedableRng;

    /// A box and a few points on its surface plus ground points.
    pub fn sample() -> Sample {
        let boxes =
            vec![Box3d::new(10.0, 5.0, -1.0, 4.0, 2.0, 1.6, 0.3), Box3d::new(-6.0, 3.0, -0.9, 0.8, 0.6, 1.8, -1.0)];
        let mut points = Vec::new();
        for b in &boxes {
            for k in 0..50 {
                let t = k as f64 / 50.0;
                let local = [(t - 0.5) * b.dx * 0.9, 0.4 * b.dy * (k % 2) as f64 - 0.2 * b.dy, (t - 0.5) * b.dz * 0.8];
                let (s, c) = b.heading.sin_cos();
                points.push([
                    (b.x + c * local[0] - s * local[1]) as f32,
                    (b.y + s * local[0] + c * local[1]) as f32,
                    (b.z + local[2]) as f32,
                    0.5,
                ]);
            }
        }
        for i in 0..100 {
            points.push([i as f32 * 0.3 - 15.0, (i % 7) as f32 - 3.0, -1.9, 0.1]);
        }
        Sample { points, boxes, classes: vec![0, 1], ..Default::default() }
    }

    pub fn rng(seed: u64) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(seed)
    }

    /// Every box keeps exactly the points it had (the transform moved both consistently).
    pub fn assert_points_follow_boxes(before: &Sample, after: &Sample) {
        for (b0, b1) in before.boxes.iter().zip(&after.boxes) {
            assert_eq!(
                points_in_box(&before.points, b0).len(),
                points_in_box(&after.points, b1).len(),
                "{b0:?} → {b1:?}"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::test_util::*;
    use super::*;

    /// The test sample with an ignored copy of each of its boxes.
    fn with_ignored_copies() -> Sample {
        let mut s = sample();
        s.ignored = s.boxes.clone();
        s.ignored_classes = s.classes.clone();
        s
    }

    /// Every scene transform moves an ignored box exactly like a regular box at the same place;
    /// object rotation leaves ignored boxes alone.
    #[test]
    fn scene_transforms_move_ignored_boxes_like_boxes() {
        let scene: Vec<Box<dyn Augment>> = vec![
            Box::new(WorldFlip(WorldFlipConfig { along_x: true, along_y: false, probability: 1.0 })),
            Box::new(WorldFlip(WorldFlipConfig { along_x: false, along_y: true, probability: 1.0 })),
            Box::new(WorldRotation(WorldRotationConfig::default())),
            Box::new(WorldScaling(WorldScalingConfig { range: [0.9, 1.1] })),
            Box::new(RandomPlatformJitter(RandomPlatformJitterConfig::default())),
        ];
        for (i, a) in scene.iter().enumerate() {
            let s0 = Sample { sensor_z: 1.8, ..with_ignored_copies() };
            let mut s = s0.clone();
            a.apply(&mut s, &mut rng(20 + i as u64));
            assert_ne!(s.boxes, s0.boxes, "{} moved the boxes", a.name());
            assert_eq!(s.ignored, s.boxes, "{} moved the ignored boxes like the boxes", a.name());
            assert_eq!(s.ignored_classes, s0.ignored_classes);
        }
        let s0 = with_ignored_copies();
        let mut s = s0.clone();
        RandomObjectRotation(RandomObjectRotationConfig { range_rad: [0.2, 0.4] }).apply(&mut s, &mut rng(3));
        assert_ne!(s.boxes, s0.boxes);
        assert_eq!(s.ignored, s0.ignored);
    }
}
