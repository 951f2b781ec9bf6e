//! `pi3det autolabel`: the Pi3DET annotation pipeline (paper appendix A.6) over unlabelled
//! frames — several checkpoints × test-time augmentation → kernel-density box fusion → tracking
//! → score filter → a new Pi3DET-layout label set (an info file over the original points),
//! with a quality report per stage when the data has ground truth.
//!
//! `pi3det autolabel --data runs/demo/data/drone/val --ckpt A.safetensors --ckpt B.safetensors --tta-views flip,rot --out labels/`

use std::path::PathBuf;
use std::sync::Arc;

use crate::{DataArgs, DeviceArgs};
use anyhow::{bail, Context, Result};
use pi3det_autolabel::fusion::{fuse, FusionConfig, FusionInput};
use pi3det_autolabel::quality::{quality, quality_table, Quality};
use pi3det_autolabel::tracking::{track_dataset, TrackingConfig};
use pi3det_autolabel::LabelSet;
use pi3det_data::{DataError, Dataset, FrameInfo, FrameMap, Mapped, PointCloud};
use pi3det_nn::data_loader::Subset;
use pi3det_nn::preprocess::{Level, Preprocessor};
use pi3det_nn::{checkpoint, detect, Detector};
use serde::Serialize;

/// Label unlabelled frames with several detectors, test-time augmentation, box fusion and
/// tracking; write a Pi3DET-layout label set and, with ground truth, its quality per stage.
#[derive(clap::Args, Debug, Clone)]
pub struct AutolabelArgs {
    #[command(flatten)]
    pub data: DataArgs,
    /// A trained or adapted checkpoint (repeat for an ensemble).
    #[arg(long = "ckpt", required = true)]
    pub ckpt: Vec<PathBuf>,
    /// Test-time augmentation views per checkpoint, comma-separated: none (the frame as it is),
    /// flip (mirrored left/right), rot (turned by ±--tta-rot-deg about the vertical). (`--tta`
    /// is the old spelling: elsewhere `--tta` is a switch.)
    #[arg(long, alias = "tta", value_delimiter = ',', default_value = "none")]
    pub tta_views: Vec<TtaKind>,
    #[arg(long, default_value_t = 15.0)]
    pub tta_rot_deg: f64,
    /// Levelling of each frame (as `pi3det detect`: by default to each checkpoint's training
    /// sensor height).
    #[command(flatten)]
    pub level: crate::args::LevelArgs,
    /// Fusion parameters (TOML, `pi3det fuse --print-config`).
    #[arg(long)]
    pub fusion_config: Option<PathBuf>,
    /// Members a fused cluster needs [default: the config's, at most a third of the inputs, at least 1].
    #[arg(long)]
    pub min_members: Option<usize>,
    /// Tracking parameters (TOML, `pi3det track --print-config`).
    #[arg(long)]
    pub tracking_config: Option<PathBuf>,
    /// Frame spacing for data without timestamps.
    #[arg(long, value_name = "HZ")]
    pub frame_rate: Option<f64>,
    /// Final labels keep boxes scoring at least this.
    #[arg(long, default_value_t = 0.3)]
    pub min_score: f64,
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long)]
    pub overwrite: bool,
    #[arg(long, default_value_t = 1)]
    pub batch_size: usize,
    #[command(flatten)]
    pub device: DeviceArgs,
}

#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum TtaKind {
    None,
    Flip,
    Rot,
}

pub use pi3det_geometry::View;

/// A dataset seen through a [`View`]: points and boxes moved.
#[derive(Debug, Clone, Copy)]
pub struct ViewMap(pub View);

impl ViewMap {
    /// A frame's info seen in this view: boxes moved, and the pose — which Virtual Platform Pose
    /// levels by — turned with the points (`world_from_view = world_from_lidar · Rz(−yaw)`). A
    /// mirror is no rigid motion, so a flipped view drops the pose and VPP levels it from its own
    /// ground plane instead.
    fn info_in_view(self, mut info: FrameInfo) -> FrameInfo {
        let v = self.0;
        info.objects.iter_mut().for_each(|o| o.box3d = v.into_view(&o.box3d));
        info.world_from_lidar = match (v.flip_y, info.world_from_lidar) {
            (true, _) | (_, None) => None,
            (false, Some(pose)) => Some(
                pose * pi3det_geometry::Pose::from_parts(
                    nalgebra::Translation3::identity(),
                    nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, -v.yaw_rad),
                ),
            ),
        };
        info
    }
}

pub fn views(kinds: &[TtaKind], rot_deg: f64) -> Vec<View> {
    let mut v = Vec::new();
    let id = View { flip_y: false, yaw_rad: 0.0 };
    for k in kinds {
        match k {
            TtaKind::None => v.push(id),
            TtaKind::Flip => v.push(View { flip_y: true, ..id }),
            TtaKind::Rot => {
                v.push(View { yaw_rad: rot_deg.to_radians(), ..id });
                v.push(View { yaw_rad: -rot_deg.to_radians(), ..id });
            }
        }
    }
    v.dedup();
    v
}

impl FrameMap for ViewMap {
    fn info(&self, _index: usize, info: FrameInfo) -> FrameInfo {
        self.info_in_view(info)
    }
    fn points(&self, _index: usize, points: PointCloud) -> std::result::Result<PointCloud, DataError> {
        let channels = points.channels().to_vec();
        let stride = points.stride();
        let mut data = points.into_vec();
        for p in data.chunks_exact_mut(stride) {
            let (x, y) = self.0.apply_xy(f64::from(p[0]), f64::from(p[1]));
            p[0] = x as f32;
            p[1] = y as f32;
        }
        PointCloud::from_vec(data, channels)
    }
}

#[derive(Debug, Serialize)]
struct Report {
    inputs: Vec<String>,
    frames: usize,
    min_members: usize,
    fusion: pi3det_autolabel::fusion::FusionStats,
    tracking: pi3det_autolabel::tracking::TrackingStats,
    final_boxes: usize,
    info_file: PathBuf,
    quality: Vec<(String, Vec<Quality>)>,
}

/// What [`ensemble`] labels with.
pub struct EnsembleOptions<'a> {
    pub subset: &'a Subset,
    /// `subset`'s infos.
    pub infos: &'a [FrameInfo],
    pub checkpoints: &'a [PathBuf],
    pub views: &'a [View],
    /// How each checkpoint's frames are levelled ([`Level::Trained`]: to its own training height).
    pub level: Level,
    /// The frames' `shift_z` into the detectors' frame instead of their configs' (without VPP).
    pub shift_z: Option<f64>,
    pub fusion: FusionConfig,
    /// Members a fused cluster needs (default: the config's, at most a third of the inputs, at least 1).
    pub min_members: Option<usize>,
    pub tracking: &'a TrackingConfig,
    pub frame_rate: Option<f64>,
    pub min_score: f64,
    pub batch_size: usize,
    pub device: tch::Device,
    /// Overrides the checkpoints' `precision` (`--precision`).
    pub precision: Option<pi3det_nn::precision::Precision>,
}

/// MS3D++'s labels: every checkpoint × view → kernel-density box fusion → tracking → score filter.
pub struct Ensemble {
    pub names: Vec<String>,
    pub inputs: Vec<FusionInput>,
    pub min_members: usize,
    pub fusion: FusionConfig,
    pub fusion_stats: pi3det_autolabel::fusion::FusionStats,
    pub fused: LabelSet,
    pub tracked: pi3det_autolabel::tracking::Tracked,
    pub final_labels: LabelSet,
    pub final_ids: std::collections::BTreeMap<String, Vec<u64>>,
}

/// Detections of `det` on `subset` seen through `view`, mapped back to the frames' own LiDAR frame.
/// The checkpoint's own test-time augmentation stays off: the ensemble chooses the views.
pub fn detect_in_view(
    det: &Detector,
    prep: Preprocessor,
    subset: &Subset,
    view: View,
    batch_size: usize,
) -> Result<Vec<detect::FrameDetections>> {
    let ds: Arc<dyn Dataset> = Arc::new(Mapped { inner: subset.dataset.clone(), map: ViewMap(view) });
    let sub = Subset { dataset: ds, indices: subset.indices.clone() };
    let (mut frames, _) = detect::detect_with(det, Arc::new(prep), &sub, batch_size, false, &mut |_, _| {})?;
    for f in &mut frames {
        f.objects.iter_mut().for_each(|o| o.box3d = view.out_of_view(&o.box3d));
        f.info = view_back(f.info.clone(), view);
    }
    Ok(frames)
}

/// A view's info with the boxes back in the original frame.
fn view_back(mut info: FrameInfo, view: View) -> FrameInfo {
    info.objects.iter_mut().for_each(|o| o.box3d = view.out_of_view(&o.box3d));
    info
}

/// Runs the ensemble; `on_input` sees each checkpoint × view's labels as they are made.
pub fn ensemble(o: &EnsembleOptions<'_>, on_input: &mut dyn FnMut(&str, &LabelSet) -> Result<()>) -> Result<Ensemble> {
    let mut inputs = Vec::new();
    let mut names = Vec::new();
    for (k, ckpt) in o.checkpoints.iter().enumerate() {
        let mut ck = checkpoint::load(ckpt)?;
        if let Some(p) = o.precision {
            ck.config.precision = p;
            ck.config.train.precision = p;
        }
        let mut det = Detector::new(&ck.config, o.device)?;
        ck.load_into(&mut det, ckpt)?;
        for view in o.views {
            // A fresh preprocessor per view: VPP caches its transform per point file.
            let mut cfg = ck.config.clone();
            if let Some(z) = o.shift_z {
                cfg.shift_z = z;
            }
            let mut prep = Preprocessor::new(&cfg)?;
            if let Some(h) = o.level.height_m(&ck.config) {
                prep = prep.with_frame_transform(crate::detect::vpp(&ck.config, h)?);
            }
            let frames = detect_in_view(&det, prep, o.subset, *view, o.batch_size)?;
            let mut labels = LabelSet::default();
            for f in frames {
                labels.frames.insert(f.info.id, f.objects);
            }
            let name = format!("{k}_{}", view.name());
            on_input(&name, &labels)?;
            names.push(format!("{} {}", ckpt.display(), view.name()));
            inputs.push(FusionInput { labels, class_weights: vec![1.0; o.fusion.classes.len()] });
        }
    }
    let min_members = o.min_members.unwrap_or_else(|| {
        let configured = o.fusion.classes.iter().map(|c| c.min_members).max().unwrap_or(1);
        configured.min(inputs.len() / 3).max(1)
    });
    let mut fusion = o.fusion.clone();
    fusion.classes.iter_mut().for_each(|c| c.min_members = min_members);
    let (fused, fusion_stats) = fuse(&inputs, &fusion)?;
    let tracked = track_dataset(o.infos, &fused, o.tracking, o.frame_rate)?;
    let mut final_labels = LabelSet::default();
    let mut final_ids = std::collections::BTreeMap::new();
    for (id, objects) in &tracked.labels.frames {
        let ids = &tracked.track_ids[id];
        let keep: Vec<usize> = (0..objects.len()).filter(|&i| objects[i].score.unwrap_or(1.0) >= o.min_score).collect();
        final_labels.frames.insert(id.clone(), keep.iter().map(|&i| objects[i].clone()).collect());
        final_ids.insert(id.clone(), keep.iter().map(|&i| ids[i]).collect::<Vec<_>>());
    }
    Ok(Ensemble { names, inputs, min_members, fusion, fusion_stats, fused, tracked, final_labels, final_ids })
}

pub fn run_autolabel(args: &AutolabelArgs) -> Result<()> {
    if !args.tta_rot_deg.is_finite() || !args.min_score.is_finite() {
        bail!("--tta-rot-deg and --min-score must be finite numbers");
    }
    let info_name = |split: &str| format!("pi3det_infos_{split}.pkl");
    let split = args.data.split.clone().unwrap_or_else(|| "val".into());
    for name in ["fused.jsonl", "tracked.jsonl", "labels.jsonl", "autolabel.json", &info_name(&split)] {
        let p = args.out.join(name);
        if p.exists() && !args.overwrite {
            bail!("{} exists; pass --overwrite to replace it", p.display());
        }
    }
    let fusion_cfg = match &args.fusion_config {
        Some(p) => FusionConfig::from_file(p)?,
        None => FusionConfig::default(),
    };
    let tracking_cfg = match &args.tracking_config {
        Some(p) => TrackingConfig::from_file(p)?,
        None => TrackingConfig::default(),
    };
    let device = args.device.setup(0)?;
    let subset = args.data.subset(&split, 0)?;
    let infos = subset.infos()?;
    std::fs::create_dir_all(args.out.join("detections")).with_context(|| format!("creating {}", args.out.display()))?;
    let views = views(&args.tta_views, args.tta_rot_deg);
    let e = ensemble(
        &EnsembleOptions {
            subset: &subset,
            infos: &infos,
            checkpoints: &args.ckpt,
            views: &views,
            level: args.level.level(),
            shift_z: None,
            fusion: fusion_cfg.clone(),
            min_members: args.min_members,
            tracking: &tracking_cfg,
            frame_rate: args.frame_rate,
            min_score: args.min_score,
            batch_size: args.batch_size,
            device,
            precision: args.device.precision,
        },
        &mut |name, labels| {
            let path = args.out.join("detections").join(format!("{name}.jsonl"));
            eprintln!("{name}: {} detections", labels.num_boxes());
            labels.write_jsonl(&path, None, true).map_err(anyhow::Error::from)
        },
    )?;
    let (names, inputs, min_members, fusion_stats, fused, tracked, final_labels, final_ids) =
        (e.names, e.inputs, e.min_members, e.fusion_stats, e.fused, e.tracked, e.final_labels, e.final_ids);
    let fusion_cfg = e.fusion;
    fused.write_jsonl(&args.out.join("fused.jsonl"), None, true)?;
    tracked.labels.write_jsonl(&args.out.join("tracked.jsonl"), Some(&tracked.track_ids), true)?;
    final_labels.write_jsonl(&args.out.join("labels.jsonl"), Some(&final_ids), true)?;
    // The label set: the data's frames with the final boxes, over the original point files.
    let labelled: Vec<FrameInfo> = infos
        .iter()
        .map(|info| FrameInfo {
            objects: final_labels.frames.get(&info.id).cloned().unwrap_or_default(),
            ..info.clone()
        })
        .collect();
    let info_file = args.out.join(info_name(&split));
    pi3det_data::pi3det::write_infos(&info_file, &labelled, true)?;
    let has_gt = infos.iter().any(|i| !i.objects.is_empty());
    let mut rows = Vec::new();
    if has_gt {
        let classes: Vec<&str> = fusion_cfg
            .classes
            .iter()
            .map(|c| c.name.as_str())
            .filter(|c| {
                infos.iter().any(|i| i.objects.iter().any(|o| class_name(&fusion_cfg, &o.name).as_deref() == Some(*c)))
            })
            .collect();
        let q = |l: &LabelSet| quality(l, &infos, &classes, |n| class_name(&fusion_cfg, n), &[0.5, 0.7]);
        for (name, input) in names.iter().zip(&inputs) {
            rows.push((name.clone(), q(&input.labels)));
        }
        rows.push(("fused".to_string(), q(&fused)));
        rows.push(("tracked".to_string(), q(&tracked.labels)));
        rows.push((format!("final (score ≥ {})", args.min_score), q(&final_labels)));
    }
    let report = Report {
        inputs: names,
        frames: infos.len(),
        min_members,
        fusion: fusion_stats,
        tracking: tracked.stats.clone(),
        final_boxes: final_labels.num_boxes(),
        info_file: info_file.clone(),
        quality: rows.clone(),
    };
    std::fs::write(args.out.join("autolabel.json"), serde_json::to_vec_pretty(&report)?)
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "{} frames, {} inputs → {} fused, {} tracked ({} tracks, {} interpolated), {} final labels → {}",
        infos.len(),
        inputs.len(),
        report.fusion.fused,
        tracked.labels.num_boxes(),
        tracked.stats.tracks,
        tracked.stats.interpolated_boxes,
        report.final_boxes,
        info_file.display()
    );
    if has_gt {
        print!("{}", quality_table("labels", &rows));
    }
    Ok(())
}

fn class_name(cfg: &FusionConfig, name: &str) -> Option<String> {
    cfg.class_index(name).map(|k| cfg.classes[k].name.clone())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_move_the_pose_with_the_points() {
        let names: Vec<String> =
            views(&[TtaKind::None, TtaKind::Flip, TtaKind::Rot], 15.0).iter().map(View::name).collect();
        assert_eq!(names, ["none", "flip", "rot+15", "rot-15"]);
        // A turned view keeps every point where it is in the world.
        let mut info = FrameInfo::new("0", "x.bin".into());
        let world_from_lidar = pi3det_geometry::Pose::from_parts(
            nalgebra::Translation3::new(5.0, -2.0, 1.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.05, -0.03, 0.4),
        );
        info.world_from_lidar = Some(world_from_lidar);
        let rot = View { flip_y: false, yaw_rad: 0.3 };
        let world_from_view = ViewMap(rot).info_in_view(info.clone()).world_from_lidar.unwrap();
        let p = nalgebra::Point3::new(7.0, 3.0, -1.0);
        let (x, y) = rot.apply_xy(p.x, p.y);
        let moved = world_from_view * nalgebra::Point3::new(x, y, p.z);
        assert!((moved - world_from_lidar * p).norm() < 1e-9);
        let flip = View { flip_y: true, yaw_rad: 0.0 };
        assert!(ViewMap(flip).info_in_view(info).world_from_lidar.is_none());
    }
}
