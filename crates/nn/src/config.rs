//! Detector + training configuration (TOML files under `configs/`; every field has a default, so
//! a file only states what differs).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::augment::AugmentConfig;
use crate::backbone_2d::Backbone2dConfig;
use crate::config_override::{read_config, ConfigOverride};
use crate::dense_heads::{AnchorHeadConfig, AnyAssigner, AnyDenseHead, CenterHeadConfig};
use crate::error::{NnError, Result};
use crate::necks::NeckConfig;
use crate::pillarize::{Grid, PillarizeConfig};
use crate::target_assigner::CenterMap;
use crate::vfe::PillarVfeConfig;

/// Largest BEV map (bytes, one batch) a config may ask for.
const MAX_BEV_BYTES: f64 = 8.0 * (1u64 << 30) as f64;

/// The dense head.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum HeadConfig {
    Anchor(AnchorHeadConfig),
    Center(CenterHeadConfig),
}

impl Default for HeadConfig {
    fn default() -> Self {
        Self::Anchor(AnchorHeadConfig::default())
    }
}

impl HeadConfig {
    /// The head on `in_channels` BEV channels and a map of geometry `map`.
    pub fn init(
        &self,
        vs: tch::nn::Path,
        in_channels: i64,
        num_classes: usize,
        bn: &crate::BatchNorm,
        map: &CenterMap,
    ) -> Box<dyn AnyDenseHead> {
        let k = num_classes as i64;
        match self {
            Self::Anchor(a) => Box::new(a.init(vs, in_channels, k, map)),
            Self::Center(c) => Box::new(c.init(vs, in_channels, k, bn, map)),
        }
    }

    /// The head's target assigner (run on the loader thread).
    pub fn assigner(&self, map: &CenterMap, num_classes: usize) -> Box<dyn AnyAssigner> {
        match self {
            Self::Anchor(a) => Box::new(a.assigner(map)),
            Self::Center(c) => Box::new(c.assigner(map, num_classes)),
        }
    }
}

/// Post-processing: score threshold and rotated NMS (class-agnostic, OpenPCDet semantics).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PostConfig {
    pub score_threshold: f64,
    pub nms_iou: f64,
    pub nms_pre_max: usize,
    pub nms_post_max: usize,
    /// Run NMS per class instead of over all classes at once.
    pub per_class_nms: bool,
    /// Fit each detection's bottom and top to the frame's points after NMS (absent: off).
    pub ground_fit: Option<crate::post_process::ground_fit::GroundFitConfig>,
    /// Fit each long detection's heading and BEV centre to the points on its faces, after the
    /// vertical fit (absent: off).
    pub bev_fit: Option<crate::post_process::bev_fit::BevFitConfig>,
    /// Lower the scores of small-object detections that are not upright bodies, after the fits
    /// (absent: off).
    pub upright_check: Option<crate::post_process::upright_check::UprightCheckConfig>,
    /// Test-time augmentation: views of each frame fused before the fits (absent: off).
    pub tta: Option<crate::post_process::tta::TtaConfig>,
}

impl PostConfig {
    /// Whether a post-NMS fit needs the frame's points (then the loader indexes them).
    pub fn fits_to_points(&self) -> bool {
        self.ground_fit.is_some() || self.bev_fit.is_some() || self.upright_check.is_some()
    }
}

impl Default for PostConfig {
    fn default() -> Self {
        Self {
            score_threshold: 0.1,
            nms_iou: 0.01,
            nms_pre_max: 4096,
            nms_post_max: 500,
            per_class_nms: false,
            ground_fit: None,
            bev_fit: None,
            upright_check: None,
            tta: None,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum OptimizerKind {
    Adam,
    #[default]
    AdamW,
}

/// Training schedule and data pipeline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    pub epochs: usize,
    pub batch_size: usize,
    pub optimizer: OptimizerKind,
    /// Peak learning rate of the one-cycle schedule.
    pub lr: f64,
    pub weight_decay: f64,
    /// One-cycle: start at `lr / div_factor`, peak after `pct_start` of the steps, end at
    /// `lr / div_factor / final_div_factor`; β1 cycles between `moms[0]` and `moms[1]`.
    pub div_factor: f64,
    pub final_div_factor: f64,
    pub pct_start: f64,
    pub moms: [f64; 2],
    pub beta2: f64,
    /// Global gradient-norm clip (0: off).
    pub grad_clip: f64,
    pub seed: u64,
    /// libtorch intra-op threads (0: let the runner decide, see `device::default_threads`).
    pub threads: usize,
    /// Compute precision of the 2-D backbone and the neck in training steps (the top-level
    /// `precision` is inference's). f32 by default: bf16 training cost the Pi3DET-Net preset
    /// Car AP (results/2026-12-06-mixed-precision.md).
    pub precision: crate::precision::Precision,
    /// Batches prepared ahead on the loader thread.
    pub prefetch: usize,
    /// Evaluate every this many epochs (0: only at the end); checkpoint every this many epochs.
    pub eval_every: usize,
    pub ckpt_every: usize,
    /// Checkpoints kept (older ones are deleted; the final one is always kept).
    pub keep_checkpoints: usize,
    /// Ground-truth boxes with fewer LiDAR points than this are dropped from training targets.
    pub min_points_in_gt: usize,
    /// Train on at most this many frames (0: all); evaluate on at most this many (0: all).
    pub max_train_frames: usize,
    pub max_eval_frames: usize,
    /// Augmentations, applied in order to each training frame.
    pub augment: Vec<AugmentConfig>,
}

impl Default for TrainConfig {
    /// OpenPCDet's `adam_onecycle` recipe.
    fn default() -> Self {
        Self {
            epochs: 20,
            batch_size: 4,
            optimizer: OptimizerKind::AdamW,
            lr: 0.003,
            weight_decay: 0.01,
            div_factor: 10.0,
            final_div_factor: 1e2,
            pct_start: 0.4,
            moms: [0.95, 0.85],
            beta2: 0.99,
            grad_clip: 10.0,
            seed: 0,
            threads: 0,
            precision: Default::default(),
            prefetch: 2,
            eval_every: 0,
            ckpt_every: 1,
            keep_checkpoints: 3,
            min_points_in_gt: 1,
            max_train_frames: 0,
            max_eval_frames: 0,
            augment: crate::augment::default_pipeline(),
        }
    }
}

/// Everything a detector needs, saved inside each checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorConfig {
    pub name: String,
    /// Detected classes, in output order.
    pub classes: Vec<String>,
    /// Dataset class names mapped onto `classes` (Pi3DET writes both `Car` and `Vehicle`).
    pub class_aliases: BTreeMap<String, String>,
    /// Added to point and box z when frames are read (OpenPCDet `SHIFT_COOR`); detections are
    /// shifted back.
    pub shift_z: f64,
    pub pillars: PillarizeConfig,
    /// Run the BEV network in channels-last memory layout on the CPU (faster with oneDNN).
    pub channels_last: bool,
    /// Compute precision of the 2-D backbone and the neck at inference (`f32`, `bf16`, `auto`;
    /// weights and heads stay f32, [`crate::precision`]); training's is `train.precision`.
    pub precision: crate::precision::Precision,
    pub batch_norm: crate::BatchNorm,
    /// The pillar feature net (pillar grids; voxel grids average each voxel's points instead).
    pub vfe: PillarVfeConfig,
    /// Sparse 3-D backbone over voxels (needs `[pillars] voxel_height`): SECOND, Voxel R-CNN.
    pub backbone_3d: Option<crate::backbones_3d::Backbone3dConfig>,
    pub backbone: Backbone2dConfig,
    /// Optional BEV-to-BEV module between the backbone and the head.
    pub neck: Option<NeckConfig>,
    pub head: HeadConfig,
    /// Optional second stage refining the dense head's boxes from RoI features.
    pub roi_head: Option<crate::roi_heads::RoiHeadConfig>,
    /// Pi3DET-Net's KL Probabilistic Feature Alignment on the second stage's RoI features.
    pub pfa: Option<crate::roi_heads::pfa::PfaConfig>,
    /// Scales applied to named loss terms on top of each stage's own weights (e.g. `loc = 1.5`).
    pub loss_weights: BTreeMap<String, f64>,
    pub post: PostConfig,
    pub train: TrainConfig,
    /// What the training frames looked like, recorded by training (absent from older checkpoints
    /// and from configs written by hand): inference levels each frame to this sensor height by
    /// default and stands in for a frame's lost intensity with this mean.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trained_on: Option<TrainedOn>,
}

/// The training frames' sensor height above the ground and mean intensity ([`DetectorConfig::trained_on`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedOn {
    /// Median height of the sensor above the ground it sees, over training frames (m).
    pub sensor_height_m: Option<f64>,
    /// Mean intensity of the training points, on the [0, 1] scale every reader delivers.
    pub intensity_mean: Option<f64>,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            name: "pointpillars".into(),
            classes: vec!["Car".into(), "Pedestrian".into()],
            class_aliases: [("Vehicle".to_string(), "Car".to_string())].into_iter().collect(),
            shift_z: 0.0,
            pillars: PillarizeConfig::default(),
            channels_last: true,
            precision: Default::default(),
            batch_norm: crate::BatchNorm::default(),
            vfe: PillarVfeConfig::default(),
            backbone_3d: None,
            backbone: Backbone2dConfig::default(),
            neck: None,
            head: HeadConfig::default(),
            roi_head: None,
            pfa: None,
            loss_weights: BTreeMap::new(),
            post: PostConfig::default(),
            train: TrainConfig::default(),
            trained_on: None,
        }
    }
}

impl DetectorConfig {
    pub fn from_toml_str(s: &str) -> Result<Self> {
        let cfg: Self = toml::from_str(s)?;
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn from_file(path: &Path) -> Result<Self> {
        Self::from_file_with(path, &[])
    }

    /// The file with `--set` overrides applied before it is read.
    pub fn from_file_with(path: &Path, overrides: &[ConfigOverride]) -> Result<Self> {
        let cfg: Self = read_config(path, overrides)?;
        cfg.validate().map_err(|e| NnError::InvalidConfigFile { path: path.to_path_buf(), source: Box::new(e) })?;
        Ok(cfg)
    }

    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// The config as TOML without what training recorded about its frames ([`TrainedOn`]): two
    /// configs with the same settings compare equal whether or not one was trained.
    pub fn settings_toml(&self) -> String {
        Self { trained_on: None, ..self.clone() }.to_toml()
    }

    /// Class index of a dataset class name (after aliases), if detected.
    pub fn class_index(&self, name: &str) -> Option<usize> {
        let name = self.class_aliases.get(name).map(String::as_str).unwrap_or(name);
        self.classes.iter().position(|c| c == name)
    }

    /// The sparse grid `[D, H, W]` a 3-D backbone convolves (z padded by one, as OpenPCDet).
    pub fn sparse_shape(&self) -> [i64; 3] {
        let g = Grid::new(&self.pillars).map(|g| (g.nz, g.ny, g.nx)).unwrap_or((0, 0, 0));
        crate::backbones_3d::Backbone3dConfig::input_shape(g.0, g.1, g.2)
    }

    /// Channels of the BEV map the 2-D backbone takes.
    pub fn bev_input_channels(&self) -> i64 {
        match &self.backbone_3d {
            Some(b) => b.bev_channels(self.sparse_shape()),
            None => self.vfe.out_channels(),
        }
    }

    /// Down-sampling from the point grid to the dense head's map.
    pub fn map_stride(&self) -> i64 {
        self.backbone.output_stride() * self.backbone_3d.as_ref().map_or(1, |b| b.xy_stride())
    }

    /// Checks everything that would otherwise fail deep inside training.
    pub fn validate(&self) -> Result<()> {
        if self.classes.is_empty() {
            return Err(NnError::config("classes", "classes is empty"));
        }
        if !self.shift_z.is_finite() {
            return Err(NnError::config("shift_z", "shift_z must be finite"));
        }
        if let Some(t) = &self.trained_on {
            if t.sensor_height_m.is_some_and(|h| !(h.is_finite() && h > 0.0)) {
                return Err(NnError::config(
                    "trained_on.sensor_height_m",
                    "trained_on.sensor_height_m must be a positive number of metres",
                ));
            }
            if t.intensity_mean.is_some_and(|i| !(0.0..=1.0).contains(&i)) {
                return Err(NnError::config(
                    "trained_on.intensity_mean",
                    "trained_on.intensity_mean must be within [0, 1]",
                ));
            }
        }
        let grid = Grid::new(&self.pillars)?;
        self.backbone.validate()?;
        if self.vfe.num_filters.is_empty() || self.vfe.num_filters.iter().any(|&c| c < 2) {
            return Err(NnError::config("vfe.num_filters", "vfe.num_filters must be non-empty, each ≥ 2"));
        }
        // A stacked layer outputs half its width and concatenates the pillar maximum back.
        let n_vfe = self.vfe.num_filters.len();
        if let Some(c) = self.vfe.num_filters[..n_vfe - 1].iter().find(|&&c| c % 2 == 1) {
            return Err(NnError::config("vfe.num_filters", format!(
                "vfe.num_filters {:?}: every layer but the last must be even (got {c}): it outputs half and concatenates the pillar maximum",
                self.vfe.num_filters
            )));
        }
        match (&self.backbone_3d, grid.is_voxel()) {
            (Some(b), true) => b.validate(self.sparse_shape())?,
            (Some(_), false) => {
                return Err(NnError::config(
                    "backbone_3d",
                    "backbone_3d convolves voxels: set [pillars] voxel_height (the voxels' height in metres)",
                ))
            }
            (None, true) => return Err(NnError::config(
                "pillars.voxel_height",
                "[pillars] voxel_height makes voxels, which need a [backbone_3d] (e.g. type = \"voxel_backbone_8x\")",
            )),
            (None, false) => {}
        }
        // The scattered BEV map of one batch must fit in memory.
        let s3 = self.backbone_3d.as_ref().map_or(1, |b| b.xy_stride()) as f64;
        let bev_bytes = (grid.nx * grid.ny) as f64 / (s3 * s3)
            * self.bev_input_channels() as f64
            * 4.0
            * self.train.batch_size as f64;
        if bev_bytes > MAX_BEV_BYTES {
            return Err(NnError::config("pillars", format!(
                "pillar grid {}×{} with {} channels at batch {} needs a {:.1} GiB BEV map (limit {:.0} GiB): use larger pillars or a smaller range",
                grid.nx,
                grid.ny,
                self.vfe.out_channels(),
                self.train.batch_size,
                bev_bytes / (1u64 << 30) as f64,
                MAX_BEV_BYTES / (1u64 << 30) as f64
            )));
        }
        let p = &self.post;
        if !(0.0..1.0).contains(&p.score_threshold) || !(0.0..=1.0).contains(&p.nms_iou) {
            return Err(NnError::config(
                "post",
                format!(
                    "post: score_threshold must be in [0, 1) and nms_iou in [0, 1] (got {} and {})",
                    p.score_threshold, p.nms_iou
                ),
            ));
        }
        if p.nms_pre_max == 0 || p.nms_post_max == 0 {
            return Err(NnError::config("post", "post: nms_pre_max and nms_post_max must be positive"));
        }
        if let Some(g) = &p.ground_fit {
            g.validate()?;
        }
        if let Some(b) = &p.bev_fit {
            b.validate()?;
        }
        if let Some(u) = &p.upright_check {
            u.validate(&self.classes)?;
        }
        if let Some(t) = &p.tta {
            t.validate(&self.classes)?;
        }
        let total_stride: i64 = self.backbone.layer_strides.iter().product::<i64>()
            * self.backbone_3d.as_ref().map_or(1, |b| b.xy_stride());
        if grid.nx as i64 % total_stride != 0 || grid.ny as i64 % total_stride != 0 {
            return Err(NnError::config(
                "pillars",
                format!(
                    "pillar grid {}×{} is not divisible by the backbone's total stride {total_stride}",
                    grid.nx, grid.ny
                ),
            ));
        }
        match &self.head {
            HeadConfig::Anchor(a) => {
                let names: Vec<&str> = a.anchors.iter().map(|a| a.class.as_str()).collect();
                let classes: Vec<&str> = self.classes.iter().map(String::as_str).collect();
                if names != classes {
                    return Err(NnError::config("head.anchors", format!(
                        "head.anchors must list one entry per class, in the order of classes {classes:?} (found {names:?})"
                    )));
                }
                for c in &a.anchors {
                    c.validate()?;
                }
            }
            HeadConfig::Center(c) => {
                if c.shared_channels < 1 || c.num_head_convs == 0 || c.max_objects_per_frame < 1 {
                    return Err(NnError::config(
                        "head",
                        "center head: shared_channels, num_head_convs and max_objects_per_frame must be positive",
                    ));
                }
            }
        }
        if let Some(r) = &self.roi_head {
            r.validate()?;
            if r.voxel_pool.is_some() && self.backbone_3d.is_none() {
                return Err(NnError::config(
                    "roi_head.voxel_pool",
                    "roi_head.voxel_pool pools voxels: it needs a [backbone_3d] (a voxel detector)",
                ));
            }
            if r.point_pool.is_some() && self.pillars.voxel_height.is_some() {
                return Err(NnError::config(
                    "roi_head.point_pool",
                    "roi_head.point_pool reads pillars: it does not work on a voxel grid (voxel_height)",
                ));
            }
        }
        if let Some(n) = &self.neck {
            n.validate()?;
        }
        if let Some(p) = &self.pfa {
            p.validate()?;
            if self.roi_head.is_none() {
                return Err(NnError::config("pfa", "pfa aligns RoI features: it needs a [roi_head]"));
            }
        }
        if let Some((k, w)) = self.loss_weights.iter().find(|(_, w)| !(w.is_finite() && **w >= 0.0)) {
            return Err(NnError::config("loss_weights", format!("loss_weights.{k} = {w}: must be finite and ≥ 0")));
        }
        let t = &self.train;
        if t.batch_size == 0 || t.epochs == 0 {
            return Err(NnError::config("train.batch_size", "train.batch_size and train.epochs must be positive"));
        }
        if !(t.lr > 0.0 && t.lr.is_finite()) || t.div_factor <= 0.0 || t.final_div_factor <= 0.0 {
            return Err(NnError::config("train", "train.lr, div_factor and final_div_factor must be positive"));
        }
        if !(0.0..=1.0).contains(&t.pct_start) {
            return Err(NnError::config("train.pct_start", "train.pct_start must be in [0, 1]"));
        }
        for a in &t.augment {
            a.validate()?;
            if let AugmentConfig::GtSampling(g) = a {
                let known = |c: &String| self.classes.contains(c);
                let unknown: Vec<&String> =
                    g.sample.iter().map(|s| &s.class).chain(g.min_points.keys()).filter(|c| !known(c)).collect();
                if !unknown.is_empty() {
                    return Err(NnError::config(
                        "train.augment.gt_sampling",
                        format!(
                            "gt_sampling names classes {unknown:?} that are not among the detector's classes {:?}",
                            self.classes
                        ),
                    ));
                }
            }
            if let AugmentConfig::StatisticalNormalization(sn) = a {
                let unknown: Vec<&String> = sn.size_delta_m.keys().filter(|c| !self.classes.contains(c)).collect();
                if !unknown.is_empty() {
                    return Err(NnError::config("train.augment.statistical_normalization", format!(
                        "statistical_normalization names classes {unknown:?} that are not among the detector's classes {:?}",
                        self.classes
                    )));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 500, failure_persistence: None, ..Default::default() })]

        /// Bounded fuzzing of the detector TOML (the demo's preset, mutated): a configuration or an
        /// error, never a panic.
        #[test]
        fn mutated_presets_parse_or_fail_cleanly(
            e in proptest::collection::vec((proptest::prelude::any::<usize>(), proptest::prelude::any::<u8>(), proptest::prelude::any::<bool>()), 1..8)
        ) {
            let mut b = include_str!("../../../configs/pointpillars_rcnn_cpu.toml").as_bytes().to_vec();
            for (i, v, insert) in e {
                let at = i % b.len();
                if insert { b.insert(at, v) } else { b[at] = v }
            }
            let _ = DetectorConfig::from_toml_str(&String::from_utf8_lossy(&b));
        }
    }

    #[test]
    fn default_round_trips_through_toml() {
        let cfg = DetectorConfig::default();
        cfg.validate().unwrap();
        let back = DetectorConfig::from_toml_str(&cfg.to_toml()).unwrap();
        assert_eq!(back, cfg);
    }

    #[test]
    fn rejects_unknown_fields_and_bad_values() {
        assert!(DetectorConfig::from_toml_str("epochz = 3").is_err());
        assert!(DetectorConfig::from_toml_str("[train]\nbatch_size = 0").is_err());
        assert!(DetectorConfig::from_toml_str("classes = [\"Car\"]").is_err(), "anchors must match classes");
        let cfg = DetectorConfig::from_toml_str("[head]\ntype = \"center\"\nshared_channels = 32").unwrap();
        assert!(matches!(cfg.head, HeadConfig::Center(ref c) if c.shared_channels == 32));
        assert_eq!(cfg.class_index("Vehicle"), Some(0));
        assert_eq!(cfg.class_index("Cyclist"), None);
    }

    /// Each bad value is refused with a message naming it, never a panic later.
    #[test]
    fn bad_values_name_the_field() {
        let err = |toml: &str| DetectorConfig::from_toml_str(toml).unwrap_err().to_string();
        assert!(err("[vfe]\nnum_filters = [33, 64]").contains("even"));
        assert!(err(
            "[pillars]\npillar_size = [0.02, 0.02]\npoint_cloud_range = [-80.0, -80.0, -3.0, 80.0, 80.0, 1.0]"
        )
        .contains("GiB"));
        assert!(err("[post]\nscore_threshold = -0.1").contains("score_threshold"));
        assert!(err("[post.ground_fit]\nground_quantile = 2.0").contains("ground_quantile"));
        assert!(err("[post.ground_fit]\nmargin_m = 0.0").contains("margin_m"));
        assert!(err("[post.ground_fit]\nmargins = 1.0").contains("margins"));
        let fit = DetectorConfig::from_toml_str("[post.ground_fit]\nmax_shift_m = 0.5").unwrap();
        assert_eq!(fit.post.ground_fit.map(|g| g.max_shift_m), Some(0.5));
        assert!(err("[post.bev_fit]\nheading_step_rad = 0.0").contains("heading_step_rad"));
        let bev = DetectorConfig::from_toml_str("[post.bev_fit]\nmin_points = 50").unwrap();
        assert_eq!(bev.post.bev_fit.map(|b| b.min_points), Some(50));
        assert!(err("[post.upright_check]\nclasses = [\"Cyclist\"]").contains("Cyclist"));
        assert!(err("[post.upright_check]\nscore_factor = -0.5").contains("score_factor"));
        let up = DetectorConfig::from_toml_str("[post.upright_check]").unwrap();
        assert_eq!(up.post.upright_check.map(|u| u.classes), Some(vec!["Pedestrian".to_string()]));
        assert!(err("[post.tta]\nyaw_deg = [400.0]").contains("yaw_deg"));
        assert!(err("[post.tta.class_fusion_iou]\nCyclist = 0.4").contains("Cyclist"));
        let tta = DetectorConfig::from_toml_str("[post.tta]").unwrap();
        assert_eq!(tta.post.tta.map(|t| t.views().len()), Some(6));
        let unknown = "[[train.augment]]\ntype = \"gt_sampling\"\nsample = [{ class = \"Cyclist\", count = 5 }]";
        assert!(err(unknown).contains("Cyclist"));
        assert!(err("[head]\ntype = \"anchor\"\nanchors = []").contains("head.anchors"));
        // Voxels and a sparse backbone come together, and the grid must survive its strides.
        assert!(err("[pillars]\nvoxel_height = 0.2").contains("backbone_3d"));
        assert!(err("[backbone_3d]\ntype = \"voxel_backbone_8x\"").contains("voxel_height"));
        let coarse = "[pillars]\nvoxel_height = 0.5\n[backbone_3d]\ntype = \"voxel_backbone_8x\"";
        assert!(err(coarse).contains("25 voxels"));
        assert!(err("[roi_head.voxel_pool]\ngrid_size = 4").contains("backbone_3d"));
        let voxel_points = format!("{}\n[roi_head.point_pool]\n", include_str!("../../../configs/second_iou_cpu.toml"));
        assert!(err(&voxel_points).contains("point_pool"), "{}", err(&voxel_points));
        assert!(err("[roi_head.point_pool]\nlattice = 0").contains("lattice"));
    }

    #[test]
    fn presets_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        for name in [
            "pointpillars_cpu.toml",
            "pointpillars_paper.toml",
            "centerpoint_cpu.toml",
            "pointpillars_rcnn_cpu.toml",
            "pointpillars_rcnn_points_cpu.toml",
            "centerpoint_rcnn_cpu.toml",
            "pointpillars_rcnn_paper.toml",
            "second_cpu.toml",
            "second_iou_cpu.toml",
            "second_iou_paper.toml",
            "voxel_rcnn_cpu.toml",
        ] {
            let cfg = DetectorConfig::from_file(&dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(cfg.roi_head.is_some(), name.contains("rcnn") || name.contains("iou"), "{name}");
            assert_eq!(cfg.backbone_3d.is_some(), name.starts_with("second") || name.starts_with("voxel"), "{name}");
        }
    }
}
