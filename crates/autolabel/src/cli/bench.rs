//! `pi3det bench autolabel`: fusion and tracking against ground truth with simulated detectors,
//! and their speed.

use std::path::PathBuf;
use std::time::Instant;

use pi3det_data::FrameInfo;

use crate::fusion::{fuse, FusionConfig, FusionInput};
use crate::labels::LabelSet;
use crate::perturb::{noise_profiles, simulate_detector, DetectorNoise};
use crate::quality::{quality, quality_table, Quality};
use crate::read_infos;
use crate::tracking::{track_dataset, TrackingConfig};
use crate::AutolabelError;

/// Fusion and tracking against ground truth and their speed: simulated detectors (ground truth
/// with seeded misses, noise, displaced boxes and false positives) on a dataset's frames.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchArgs {
    /// A labelled dataset with sequences (e.g. `pi3det simulate` output).
    #[arg(long)]
    pub data: PathBuf,
    /// Simulated detectors to fuse.
    #[arg(long, default_value_t = 3)]
    pub detectors: usize,
    /// Cluster size for fusion (`min_members` of every class).
    #[arg(long, default_value_t = 2)]
    pub min_members: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Fusion parameters (TOML) instead of the defaults with --min-members.
    #[arg(long)]
    pub fusion_config: Option<PathBuf>,
    /// Tracking parameters (TOML).
    #[arg(long)]
    pub tracking_config: Option<PathBuf>,
    /// Also time fusion of 100k detections from 8 inputs and tracking of a 1,000-frame sequence.
    #[arg(long)]
    pub speed: bool,
}

pub fn run(args: &BenchArgs) -> Result<(), AutolabelError> {
    let infos = read_infos(&args.data)?;
    let fusion = match &args.fusion_config {
        Some(p) => FusionConfig::from_file(p)?,
        None => {
            let mut f = FusionConfig::default();
            f.classes.iter_mut().for_each(|c| c.min_members = args.min_members);
            f
        }
    };
    let tracking = match &args.tracking_config {
        Some(p) => TrackingConfig::from_file(p)?,
        None => TrackingConfig::default(),
    };
    let profiles = noise_profiles(args.detectors);
    let singles: Vec<LabelSet> =
        profiles.iter().enumerate().map(|(k, n)| simulate_detector(&infos, n, args.seed * 1000 + k as u64)).collect();
    let inputs: Vec<FusionInput> = singles
        .iter()
        .map(|l| FusionInput { labels: l.clone(), class_weights: vec![1.0; fusion.classes.len()] })
        .collect();
    let t0 = Instant::now();
    let (fused, _) = fuse(&inputs, &fusion)?;
    let fuse_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let tracked = track_dataset(&infos, &fused, &tracking, Some(10.0))?;
    let track_s = t0.elapsed().as_secs_f64();
    let classes = present_classes(&infos, &fusion);
    let class_of = |n: &str| fusion.class_index(n).map(|k| fusion.classes[k].name.clone());
    let ious = [0.5, 0.7];
    let mut rows: Vec<(String, Vec<Quality>)> = singles
        .iter()
        .enumerate()
        .map(|(k, l)| (format!("detector {}", k + 1), quality(l, &infos, &classes, class_of, &ious)))
        .collect();
    rows.push(("fused".into(), quality(&fused, &infos, &classes, class_of, &ious)));
    rows.push(("tracked".into(), quality(&tracked.labels, &infos, &classes, class_of, &ious)));
    println!(
        "{} frames, {} sequences, {} simulated detectors (seed {}), fusion min_members {}\n",
        infos.len(),
        tracked.stats.sequences,
        args.detectors,
        args.seed,
        args.min_members
    );
    println!("{}", quality_table("labels", &rows));
    println!(
        "fusion {:.3} s, tracking {:.3} s ({} tracks, {} interpolated boxes)",
        fuse_s, track_s, tracked.stats.tracks, tracked.stats.interpolated_boxes
    );
    if args.speed {
        speed(&fusion)?;
    }
    Ok(())
}

fn speed(fusion: &FusionConfig) -> Result<(), AutolabelError> {
    use crate::tracking::{track_sequence, TrackFrame};
    use pi3det_data::Object;
    use pi3det_geometry::{Box3d, Pose};
    // 1,000 frames of 25 cars driving straight, seen by 8 detectors: 100k+ detections.
    let frames: Vec<FrameInfo> = (0..1000)
        .map(|f| {
            let mut info = FrameInfo::new(format!("{f:06}"), PathBuf::new());
            info.timestamp_s = Some(f as f64 * 0.1);
            info.sequence = Some("speed".into());
            info.objects = (0..25)
                .map(|c| {
                    let lane = (c % 5) as f64 * 4.0 - 8.0;
                    let x = -60.0 + ((c * 7) % 120) as f64 + (0.5 + c as f64 * 0.1) * f as f64 * 0.1;
                    Object::new(
                        "Car",
                        Box3d {
                            x: (x + 60.0) % 120.0 - 60.0,
                            y: lane,
                            z: -0.8,
                            dx: 4.2,
                            dy: 1.9,
                            dz: 1.6,
                            heading: 0.0,
                        },
                    )
                })
                .collect();
            info
        })
        .collect();
    let inputs: Vec<FusionInput> = noise_profiles(8)
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let noise = DetectorNoise { miss_near: 0.0, miss_far: 0.0, false_positives: 0.0, ..n.clone() };
            FusionInput {
                labels: simulate_detector(&frames, &noise, 77 + k as u64),
                class_weights: vec![1.0; fusion.classes.len()],
            }
        })
        .collect();
    let n: usize = inputs.iter().map(|i| i.labels.num_boxes()).sum();
    let mut cfg = fusion.clone();
    cfg.classes.iter_mut().for_each(|c| c.min_members = 4);
    let t0 = Instant::now();
    let (fused, _) = fuse(&inputs, &cfg)?;
    let fuse_s = t0.elapsed().as_secs_f64();
    let track_frames: Vec<TrackFrame> = frames
        .iter()
        .map(|f| TrackFrame {
            frame_id: f.id.clone(),
            timestamp_s: f.timestamp_s.unwrap_or(0.0),
            world_from_lidar: Pose::identity(),
            detections: fused.frames.get(&f.id).cloned().unwrap_or_default(),
        })
        .collect();
    let t0 = Instant::now();
    let mut next = 0;
    let tracks = track_sequence(&track_frames, &TrackingConfig::default(), &mut next);
    let track_s = t0.elapsed().as_secs_f64();
    println!("\n| speed | input | time | rate |\n| --- | --- | --- | --- |");
    println!(
        "| fusion (8 inputs, min_members 4) | {n} detections, 1,000 frames | {fuse_s:.3} s | {:.0} detections/s |",
        n as f64 / fuse_s
    );
    println!(
        "| tracking | 1,000 frames, {} fused boxes | {track_s:.3} s | {:.0} frames/s ({} tracks) |",
        fused.num_boxes(),
        1000.0 / track_s,
        tracks.len()
    );
    println!("({} threads)", rayon::current_num_threads());
    Ok(())
}

fn present_classes<'a>(infos: &[FrameInfo], fusion: &'a FusionConfig) -> Vec<&'a str> {
    fusion
        .classes
        .iter()
        .filter(|c| {
            infos.iter().any(|i| {
                i.objects.iter().any(|o| fusion.class_index(&o.name).is_some_and(|k| fusion.classes[k].name == c.name))
            })
        })
        .map(|c| c.name.as_str())
        .collect()
}
