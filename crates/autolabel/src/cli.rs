//! `pi3det fuse`, `pi3det track` and `pi3det bench autolabel`: arguments (clap) and runners, for
//! the `pi3det` binary to mount as subcommands.

use std::path::{Path, PathBuf};
use std::time::Instant;

use pi3det_data::FrameInfo;

use crate::fusion::{fuse, FusionConfig, FusionInput};
use crate::labels::LabelSet;
use crate::perturb::{noise_profiles, simulate_detector, DetectorNoise};
use crate::quality::{quality, quality_table, Quality};
use crate::read_infos;
use crate::tracking::{track_dataset, TrackingConfig};
use crate::AutolabelError;

/// Fuse several detectors' boxes into one label set by kernel-density box fusion (MS3D++).
#[derive(clap::Args, Debug, Clone)]
pub struct FuseArgs {
    /// Detections of one detector (repeat for each): JSON lines, result.pkl or a KITTI result folder.
    #[arg(long = "det", required = true, value_name = "DETECTIONS")]
    pub det: Vec<PathBuf>,
    /// Class weights of each --det, in order: one number for all classes (`0.5`) or per class
    /// (`Car=1,Pedestrian=0`); missing ones are 1.
    #[arg(long = "weights", value_name = "W")]
    pub weights: Vec<String>,
    /// Fusion parameters (TOML; `--print-config` shows the defaults, MS3D++'s).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Check that every frame id is one of this dataset's.
    #[arg(long, value_name = "DATASET")]
    pub data: Option<PathBuf>,
    #[arg(long, required_unless_present = "print_config")]
    pub out: Option<PathBuf>,
    #[arg(long)]
    pub overwrite: bool,
    /// Print the configuration as TOML and exit.
    #[arg(long)]
    pub print_config: bool,
}

/// Track labels over a dataset's sequences: Kalman filter, GIoU + Hungarian association,
/// interpolation of missed frames, static-object refinement; the output keeps track ids.
#[derive(clap::Args, Debug, Clone)]
pub struct TrackArgs {
    /// Labels to track (JSON lines, result.pkl or a KITTI result folder), e.g. `pi3det fuse` output.
    #[arg(long, required_unless_present = "print_config")]
    pub det: Option<PathBuf>,
    /// The dataset the labels are for (sequence, timestamp and pose of each frame).
    #[arg(long, required_unless_present = "print_config")]
    pub data: Option<PathBuf>,
    /// Tracking parameters (TOML; `--print-config` shows the defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// For data without timestamps: frames are this far apart in frame-id order.
    #[arg(long, value_name = "HZ")]
    pub frame_rate: Option<f64>,
    #[arg(long, required_unless_present = "print_config")]
    pub out: Option<PathBuf>,
    #[arg(long)]
    pub overwrite: bool,
    #[arg(long)]
    pub print_config: bool,
}

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

pub fn run_fuse(args: &FuseArgs) -> Result<(), AutolabelError> {
    let cfg = match &args.config {
        Some(p) => FusionConfig::from_file(p)?,
        None => FusionConfig::default(),
    };
    if args.print_config {
        print!("{}", toml::to_string_pretty(&cfg).map_err(|e| AutolabelError::Config(e.to_string()))?);
        return Ok(());
    }
    let out = args.out.as_deref().ok_or_else(|| AutolabelError::Input("--out is required".into()))?;
    refuse_existing(out, args.overwrite)?;
    if args.weights.len() > args.det.len() {
        return Err(AutolabelError::Input(format!("{} --weights for {} --det", args.weights.len(), args.det.len())));
    }
    let known = args.data.as_deref().map(read_infos).transpose()?;
    let mut inputs = Vec::new();
    for (k, path) in args.det.iter().enumerate() {
        let labels = LabelSet::read(path)?;
        if let Some(infos) = &known {
            labels.check_frames(infos.iter().map(|i| i.id.as_str()))?;
        }
        let class_weights = parse_weights(args.weights.get(k).map(String::as_str), &cfg)?;
        inputs.push(FusionInput { labels, class_weights });
    }
    let t0 = Instant::now();
    let (fused, stats) = fuse(&inputs, &cfg)?;
    fused.write_jsonl(out, None, args.overwrite)?;
    println!(
        "fused {} detections of {} inputs over {} frames into {} boxes ({} candidates, {} clusters) in {:.2} s → {}",
        stats.detections,
        inputs.len(),
        stats.frames,
        stats.fused,
        stats.candidates,
        stats.clusters,
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

pub fn run_track(args: &TrackArgs) -> Result<(), AutolabelError> {
    let cfg = match &args.config {
        Some(p) => TrackingConfig::from_file(p)?,
        None => TrackingConfig::default(),
    };
    if args.print_config {
        print!("{}", toml::to_string_pretty(&cfg).map_err(|e| AutolabelError::Config(e.to_string()))?);
        return Ok(());
    }
    let need = |v: &Option<PathBuf>, name: &str| {
        v.clone().ok_or_else(|| AutolabelError::Input(format!("--{name} is required")))
    };
    let (det, data, out) = (need(&args.det, "det")?, need(&args.data, "data")?, need(&args.out, "out")?);
    refuse_existing(&out, args.overwrite)?;
    let infos = read_infos(&data)?;
    let labels = LabelSet::read(&det)?;
    let t0 = Instant::now();
    let tracked = track_dataset(&infos, &labels, &cfg, args.frame_rate)?;
    tracked.labels.write_jsonl(&out, Some(&tracked.track_ids), args.overwrite)?;
    let s = &tracked.stats;
    println!(
        "tracked {} boxes over {} frames of {} sequences: {} tracks ({} static), {} boxes kept, {} interpolated, in {:.2} s → {}",
        s.input_boxes,
        s.frames,
        s.sequences,
        s.tracks,
        s.static_tracks,
        s.observed_boxes,
        s.interpolated_boxes,
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

pub fn run_bench(args: &BenchArgs) -> Result<(), AutolabelError> {
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
    println!("{}", quality_table(&rows));
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

fn parse_weights(spec: Option<&str>, cfg: &FusionConfig) -> Result<Vec<f64>, AutolabelError> {
    let mut w = vec![1.0; cfg.classes.len()];
    let Some(spec) = spec else { return Ok(w) };
    let num = |s: &str| {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| AutolabelError::Input(format!("--weights {spec:?}: {s:?} is not a non-negative number")))
    };
    if !spec.contains('=') {
        let v = num(spec)?;
        w.iter_mut().for_each(|x| *x = v);
        return Ok(w);
    }
    for part in spec.split(',') {
        let (name, value) = part
            .split_once('=')
            .ok_or_else(|| AutolabelError::Input(format!("--weights {spec:?}: expected CLASS=W, got {part:?}")))?;
        let k = cfg.class_index(name.trim()).ok_or_else(|| {
            AutolabelError::Input(format!(
                "--weights {spec:?}: unknown class {name:?} (known: {:?})",
                cfg.known_names()
            ))
        })?;
        w[k] = num(value)?;
    }
    Ok(w)
}

fn refuse_existing(out: &Path, overwrite: bool) -> Result<(), AutolabelError> {
    if out.exists() && !overwrite {
        return Err(AutolabelError::invalid(out, "exists; pass --overwrite to replace it"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_parse_or_say_why() {
        let cfg = FusionConfig::default();
        assert_eq!(parse_weights(None, &cfg).unwrap(), vec![1.0, 1.0, 1.0]);
        assert_eq!(parse_weights(Some("0.5"), &cfg).unwrap(), vec![0.5, 0.5, 0.5]);
        assert_eq!(parse_weights(Some("Vehicle=2,Pedestrian=0"), &cfg).unwrap(), vec![2.0, 0.0, 1.0]);
        let e = parse_weights(Some("Bus=1"), &cfg).unwrap_err().to_string();
        assert!(e.contains("unknown class"), "{e}");
        assert!(parse_weights(Some("Car=-1"), &cfg).is_err());
    }
}
