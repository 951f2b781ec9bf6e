//! Small configurations for tests (this crate's and the pipelines'): networks that train in
//! seconds on simulated frames. Not a preset: nothing here is tuned for accuracy.

use crate::backbone_2d::Backbone2dConfig;
use crate::config::{PostConfig, TrainConfig};
use crate::pillarize::PillarizeConfig;
use crate::roi_heads::RoiHeadConfig;
use crate::vfe::PillarVfeConfig;
use crate::DetectorConfig;

/// A single-stage PointPillars with 16-channel pillars over ±`half_range_m` at `pillar_m`, a
/// two-block backbone, one epoch at batch 1, and a low score threshold (an untrained detector
/// scores low).
pub fn tiny_detector(half_range_m: f64, pillar_m: f64) -> DetectorConfig {
    let r = half_range_m;
    DetectorConfig {
        name: "tiny".into(),
        shift_z: 1.9,
        pillars: PillarizeConfig {
            point_cloud_range: [-r, -r, -2.0, r, r, 4.0],
            pillar_size: [pillar_m, pillar_m],
            max_points_per_pillar: 8,
            max_pillars_train: 4000,
            max_pillars_test: 4000,
            voxel_height: None,
        },
        vfe: PillarVfeConfig { num_filters: vec![16] },
        backbone: Backbone2dConfig {
            layer_nums: vec![1, 1],
            layer_strides: vec![2, 2],
            num_filters: vec![16, 16],
            upsample_strides: vec![1, 2],
            num_upsample_filters: vec![16, 16],
        },
        post: PostConfig { score_threshold: 0.05, ..PostConfig::default() },
        train: TrainConfig { epochs: 1, batch_size: 1, ckpt_every: 1, ..TrainConfig::default() },
        ..DetectorConfig::default()
    }
}

/// A second stage for [`tiny_detector`].
pub fn tiny_roi_head() -> RoiHeadConfig {
    RoiHeadConfig { point_channels: 8, shared_fc: vec![32], cls_fc: vec![16], reg_fc: vec![16], ..Default::default() }
}
