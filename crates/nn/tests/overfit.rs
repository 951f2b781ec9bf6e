//! End-to-end sanity: a small detector overfits one simulated frame (pillarize → network → loss →
//! AdamW) and then finds each of its boxes — BEV IoU > 0.7 for cars, > 0.5 for pedestrians — with
//! no false positive above the score threshold. Once with the anchor head, once with the center
//! head, once through the second stage in a rotated detector frame, and once as SECOND (voxels →
//! sparse 3-D backbone → height compression) with and without the BEV second stage, and as
//! Voxel R-CNN (the second stage pooling voxels). Kept small enough for CI on two cores.

use pi3det_data::{Frame, Platform};
use std::sync::Arc;

use pi3det_geometry::{bev_iou, Pose};
use pi3det_nn::augment::Sample;
use pi3det_nn::backbone_2d::Backbone2dConfig;
use pi3det_nn::backbones_3d::{Backbone3dConfig, VoxelBackbone8xConfig};
use pi3det_nn::config::{HeadConfig, PostConfig, TrainConfig};
use pi3det_nn::data_loader::FrameGt;
use pi3det_nn::dense_heads::{AnchorHeadConfig, CenterHeadConfig};
use pi3det_nn::detect::to_objects;
use pi3det_nn::optim::{OneCycle, Optimizer};
use pi3det_nn::pillarize::PillarizeConfig;
use pi3det_nn::preprocess::{FrameTransform, Preprocessor};
use pi3det_nn::roi_heads::RoiHeadConfig;
use pi3det_nn::vfe::PillarVfeConfig;
use pi3det_nn::{Detector, DetectorConfig};
use pi3det_sim::{SequenceSpec, SimConfig};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::Device;

const HALF: f64 = 19.2;

/// A simulated vehicle frame with both classes near the sensor (boxes with ≥ 10 points, inside
/// the small test range).
fn sim_frame() -> Frame {
    let cfg = SimConfig::default();
    for index in 0..8 {
        let spec = SequenceSpec { platform: Platform::Vehicle, index, frames: 10, seed: 7, layout: None };
        let seq = pi3det_sim::Sequence::generate(&cfg, spec).expect("simulate");
        for f in 0..seq.len() {
            let sim = seq.render(f);
            let mut frame = sim.to_frame("0000000", Platform::Vehicle, &seq.name);
            frame.info.objects.retain(|o| {
                let b = o.box3d;
                b.x.abs() < HALF - 1.0 && b.y.abs() < HALF - 1.0 && o.num_points.unwrap_or(0) >= 10
            });
            let cars = frame.info.objects.iter().filter(|o| o.name == "Car").count();
            let peds = frame.info.objects.iter().filter(|o| o.name == "Pedestrian").count();
            if cars >= 2 && peds >= 1 {
                return frame;
            }
        }
    }
    panic!("no simulated frame with cars and pedestrians near the sensor");
}

fn config(head: HeadConfig) -> DetectorConfig {
    DetectorConfig {
        name: "overfit".into(),
        shift_z: 1.9,
        batch_norm: pi3det_nn::BatchNorm { eps: 1e-3, momentum: 0.1 },
        pillars: PillarizeConfig {
            point_cloud_range: [-HALF, -HALF, -2.0, HALF, HALF, 4.0],
            pillar_size: [0.4, 0.4],
            max_points_per_pillar: 16,
            max_pillars_train: 12000,
            max_pillars_test: 12000,
            voxel_height: None,
        },
        vfe: PillarVfeConfig { num_filters: vec![32] },
        backbone: Backbone2dConfig {
            layer_nums: vec![1, 1, 1],
            layer_strides: vec![2, 2, 2],
            num_filters: vec![32, 32, 64],
            upsample_strides: vec![1, 2, 4],
            num_upsample_filters: vec![32, 32, 32],
        },
        head,
        post: PostConfig {
            score_threshold: 0.3,
            nms_iou: 0.01,
            nms_pre_max: 500,
            nms_post_max: 100,
            per_class_nms: false,
            ground_fit: None,
            bev_fit: None,
            upright_check: None,
            tta: None,
        },
        train: TrainConfig { lr: 0.003, weight_decay: 0.0, augment: vec![], ..TrainConfig::default() },
        ..DetectorConfig::default()
    }
}

/// A fixed `detector_from_lidar` for every frame.
struct Fixed(Pose);

impl FrameTransform for Fixed {
    fn detector_from_lidar(&self, _frame: &Frame) -> Pose {
        self.0
    }
}

/// Trains on one frame (in the detector's frame given by `transform`, else the config's shift)
/// and checks the detections, mapped back to the LiDAR frame, against the frame's own labels.
fn overfit_with(head: HeadConfig, roi: Option<RoiHeadConfig>, transform: Option<Pose>, steps: usize) {
    overfit_config(head, roi, transform, steps, |_| {})
}

fn overfit_config(
    head: HeadConfig,
    roi: Option<RoiHeadConfig>,
    transform: Option<Pose>,
    steps: usize,
    edit: impl FnOnce(&mut DetectorConfig),
) {
    tch::manual_seed(0);
    tch::set_num_threads(1);
    let frame = sim_frame();
    let mut cfg = config(head);
    cfg.roi_head = roi;
    edit(&mut cfg);
    let mut prep = Preprocessor::new(&cfg).unwrap();
    if let Some(t) = transform {
        prep = prep.with_frame_transform(Arc::new(Fixed(t)));
    }
    let det = Detector::with_preprocessor(prep, Device::Cpu).unwrap();
    let sample: Sample = det.prep.sample(&frame, 1);
    assert!(!sample.boxes.is_empty());
    let prep = det.prep.clone();
    let pillars = prep.pillarizer().unwrap().run(&sample.points, cfg.pillars.max_pillars_train);
    let inputs = prep.collate_inputs(&[&pillars]);
    let targets = prep.collate_targets(&[&prep.targets(&sample)]).unwrap();
    let gt = [FrameGt { boxes: sample.boxes.clone(), classes: sample.classes.clone(), ..Default::default() }];
    let mut opt = Optimizer::new(det.named_trainables(), &cfg.train);
    let schedule = OneCycle::new(&cfg.train, steps);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut first = None;
    let mut last = 0.0;
    for step in 0..steps {
        let (lr, beta1) = schedule.at(step);
        let out = det.forward_train(&inputs, &gt, &mut rng).unwrap();
        let losses = det.loss(&out, &targets, &gt, pi3det_nn::detector::Domain::Source).unwrap();
        if cfg.roi_head.is_some() {
            assert!(losses.terms().iter().any(|(n, _)| *n == "rcnn_corner"), "the second stage adds its terms");
        }
        let total = losses.total();
        opt.zero_grad();
        total.backward();
        opt.clip_grad_norm(10.0);
        opt.update(lr, beta1);
        last = total.double_value(&[]);
        first.get_or_insert(last);
    }
    let first = first.unwrap();
    assert!(last < first * 0.2, "loss went from {first} to {last}");
    let dets = det.predict(&inputs).unwrap().remove(0);
    // Back to the LiDAR frame, as `pi3det detect` writes them.
    let objects = to_objects(&det, &dets, &sample.detector_from_lidar);
    let labels: Vec<_> = frame
        .info
        .objects
        .iter()
        .filter(|o| cfg.class_index(&o.name).is_some() && o.num_points.unwrap_or(1) >= 1)
        .collect();
    assert_eq!(labels.len(), sample.boxes.len());
    let mut used = vec![false; objects.len()];
    for o in &labels {
        let c = cfg.class_index(&o.name).unwrap();
        let need = if c == 0 { 0.7 } else { 0.5 };
        let best = objects
            .iter()
            .enumerate()
            .filter(|(_, d)| d.name == cfg.classes[c])
            .map(|(k, d)| (k, bev_iou(&o.box3d, &d.box3d)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let (k, iou) =
            best.unwrap_or_else(|| panic!("no detection of class {c} for {:?}; detections {objects:?}", o.box3d));
        assert!(iou > need, "class {c} box {:?}: best BEV IoU {iou:.3} ≤ {need} ({:?})", o.box3d, objects[k]);
        assert!(
            (objects[k].box3d.z - o.box3d.z).abs() < 0.5,
            "z back in the LiDAR frame: {:?} vs {:?}",
            objects[k].box3d,
            o.box3d
        );
        used[k] = true;
    }
    let fps: Vec<_> = objects.iter().zip(&used).filter(|(_, u)| !**u).map(|(d, _)| d).collect();
    assert!(fps.is_empty(), "false positives above the score threshold: {fps:?}");
}

fn overfit(head: HeadConfig, steps: usize) {
    overfit_with(head, None, None, steps)
}

#[test]
fn anchor_head_overfits_one_frame() {
    overfit(HeadConfig::Anchor(AnchorHeadConfig::default()), 250);
}

#[test]
fn center_head_overfits_one_frame() {
    let head = CenterHeadConfig { shared_channels: 32, num_head_convs: 1, ..CenterHeadConfig::default() };
    overfit(HeadConfig::Center(head), 250);
}

/// The second stage trains with the first (its loss terms in the sum) and its refined boxes are
/// the detections; the frame goes through a non-trivial `detector_from_lidar` (a yaw, a planar
/// offset and the height shift), and detections come back in the LiDAR frame.
#[test]
fn two_stage_overfits_one_frame_in_a_rotated_detector_frame() {
    let t = Pose::from_parts(
        nalgebra::Translation3::new(1.5, -2.0, 1.9),
        nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, 0.35),
    );
    let roi = small_roi();
    overfit_with(HeadConfig::Anchor(AnchorHeadConfig::default()), Some(roi), Some(t), 300);
}

/// The second stage with raw-point RoI features beside the BEV lattice, in the rotated frame
/// (the pool looks pillars up in the detector frame the points were gridded in).
#[test]
fn two_stage_with_point_pool_overfits_one_frame_in_a_rotated_detector_frame() {
    let t = Pose::from_parts(
        nalgebra::Translation3::new(1.5, -2.0, 1.9),
        nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, 0.35),
    );
    let roi = RoiHeadConfig {
        point_pool: Some(pi3det_nn::roi_heads::PointRoiPoolConfig { lattice: 6, margin: 0.4, channels: vec![16, 32] }),
        ..small_roi()
    };
    overfit_with(HeadConfig::Anchor(AnchorHeadConfig::default()), Some(roi), Some(t), 300);
}

/// SECOND's chain: mean VFE, a narrow VoxelBackBone8x, height compression, a two-block BEV
/// backbone at the 3-D backbone's stride. Voxels of 0.2 × 0.2 × 0.2 m (SECOND's are 0.05–0.1 m
/// wide): the chain is what is tested, and the coarser grid makes each step ~3× cheaper.
fn second(cfg: &mut DetectorConfig) {
    cfg.pillars.pillar_size = [0.2, 0.2];
    cfg.pillars.voxel_height = Some(0.2);
    cfg.pillars.max_points_per_pillar = 5;
    cfg.pillars.max_pillars_train = 40000;
    cfg.pillars.max_pillars_test = 40000;
    cfg.backbone_3d = Some(Backbone3dConfig::VoxelBackbone8x(VoxelBackbone8xConfig {
        channels: [8, 16, 16, 32],
        blocks: [1, 1, 1, 1],
        out_channels: 32,
    }));
    cfg.backbone = Backbone2dConfig {
        layer_nums: vec![1, 1],
        layer_strides: vec![1, 2],
        num_filters: vec![32, 64],
        upsample_strides: vec![1, 2],
        num_upsample_filters: vec![32, 32],
    };
}

#[test]
fn second_overfits_one_frame() {
    overfit_config(HeadConfig::Anchor(AnchorHeadConfig::default()), None, None, 250, second);
}

/// SECOND-IoU: SECOND with the BEV second stage.
#[test]
fn second_iou_overfits_one_frame() {
    let roi = small_roi();
    overfit_config(HeadConfig::Anchor(AnchorHeadConfig::default()), Some(roi), None, 300, second);
}

/// Voxel R-CNN: the second stage pools from the sparse backbone's stride-2 and stride-4 voxels.
#[test]
fn voxel_rcnn_overfits_one_frame() {
    let roi = RoiHeadConfig {
        voxel_pool: Some(pi3det_nn::roi_heads::VoxelRoiPoolConfig {
            grid_size: 3,
            stages: vec![
                pi3det_nn::roi_heads::VoxelPoolStage { stage: 2, radius: 1, max_neighbours: 8, channels: 16 },
                pi3det_nn::roi_heads::VoxelPoolStage { stage: 3, radius: 1, max_neighbours: 8, channels: 16 },
            ],
        }),
        ..small_roi()
    };
    overfit_config(HeadConfig::Anchor(AnchorHeadConfig::default()), Some(roi), None, 300, second);
}

/// A narrow second stage for these tests.
fn small_roi() -> RoiHeadConfig {
    RoiHeadConfig {
        shared_fc: vec![64],
        cls_fc: vec![64],
        reg_fc: vec![64],
        point_channels: 16,
        dropout: 0.0,
        ..Default::default()
    }
}
