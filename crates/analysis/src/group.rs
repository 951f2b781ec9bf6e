//! All statistics of one group of frames (a platform, a sequence, or everything), mergeable.

use serde::Serialize;

use crate::boxes::BoxStats;
use crate::ego_motion::EgoMotionStats;
use crate::elevation::ElevationStats;
use crate::error::AnalysisError;
use crate::ground::stats::GroundStats;
use crate::points::PointStats;
use crate::targets::TargetStats;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroupStats {
    pub frames: u64,
    /// From poses (frames that have one).
    pub ego: EgoMotionStats,
    /// From the ground fit (every frame when the fit is enabled).
    pub ground: GroundStats,
    pub elevation: ElevationStats,
    /// Relative pitch in the sensor frame, as the paper ("in the ego coordinate system").
    pub targets: TargetStats,
    /// The same after levelling (pose, else ground fit): the view of a gravity-aligned sensor.
    pub targets_level: TargetStats,
    pub boxes: BoxStats,
    pub points: PointStats,
}

impl GroupStats {
    pub fn new(bins: usize, bins_2d: usize) -> Self {
        Self {
            frames: 0,
            ego: EgoMotionStats::new(bins),
            ground: GroundStats::new(bins),
            elevation: ElevationStats::new(bins),
            targets: TargetStats::new(bins, bins_2d),
            targets_level: TargetStats::new(bins, bins_2d),
            boxes: BoxStats::new(bins),
            points: PointStats::new(bins),
        }
    }

    pub fn merge(&mut self, o: &GroupStats) -> Result<(), AnalysisError> {
        self.frames += o.frames;
        self.ego.merge(&o.ego)?;
        self.ground.merge(&o.ground)?;
        self.elevation.merge(&o.elevation)?;
        self.targets.merge(&o.targets)?;
        self.targets_level.merge(&o.targets_level)?;
        self.boxes.merge(&o.boxes)?;
        self.points.merge(&o.points)
    }
}
