//! The analysis pipeline: index the frames of every input, order them by sequence and time, stream
//! them in parallel chunks (rayon), fold each frame's statistics into per-platform, per-sequence
//! and overall groups in order, and smooth the ground attitude sequence by sequence.
//!
//! Memory: the frame index (a few dozen bytes a frame), one chunk of loaded frames, the per-frame
//! attitude rows of the sequence being processed, and O(bins) per group. Points are never kept.

use std::collections::BTreeMap;

use nalgebra::UnitQuaternion;
use pi3det_data::{Dataset, Format, Frame, Platform};
use pi3det_geometry::{level_from_sensor, PoseExt, RollPitchYaw};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::elevation::LevelSource;
use crate::error::AnalysisError;
use crate::ground::smoothing::{sequence_times, smooth_sequence, SmoothedAttitude, SmoothingConfig};
use crate::ground::{estimate_ground, GroundConfig, GroundEstimate};
use crate::group::GroupStats;
use crate::sample::Reservoir;

/// Which rotation levels a frame for the elevation and levelled-target statistics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum LevelChoice {
    /// The pose when the frame has one, else the ground fit, else none.
    #[default]
    Auto,
    Pose,
    Ground,
    /// No levelling: the sensor frame as stored.
    Sensor,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StatsConfig {
    /// Bins of the 1-D distributions (some use a multiple, see each statistic).
    pub bins: usize,
    /// Bins along each axis of the relative-pitch / distance histogram.
    pub bins_2d: usize,
    /// At most this many frames of each input (the first ones in sequence and time order).
    pub max_frames: Option<usize>,
    /// The ground fit; `None` skips it (no pose-free attitude).
    pub ground: Option<GroundConfig>,
    /// Temporal smoothing of the ground attitude along sequences (per-platform presets).
    pub smooth: bool,
    pub level: LevelChoice,
    /// Targets and attitudes kept per platform for scatter plots.
    pub scatter_samples: usize,
    pub seed: u64,
    /// Frames loaded at once (the parallel unit); bounds memory.
    pub chunk_frames: usize,
}

impl Default for StatsConfig {
    fn default() -> Self {
        Self {
            bins: 100,
            bins_2d: 60,
            max_frames: None,
            ground: Some(GroundConfig::default()),
            smooth: true,
            level: LevelChoice::Auto,
            scatter_samples: 3000,
            seed: 0,
            chunk_frames: 32,
        }
    }
}

/// A dataset to analyse and the name it is reported under.
pub struct Input<'a> {
    pub name: String,
    pub dataset: &'a dyn Dataset,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InputSummary {
    pub name: String,
    pub format: Format,
    pub frames_total: usize,
    pub frames_used: usize,
}

/// Attitude facts of one frame, handed out in processing order (sequence by sequence, by time).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameAttitude {
    pub input: usize,
    pub frame_id: String,
    pub platform: Platform,
    pub sequence: Option<String>,
    pub timestamp_s: Option<f64>,
    pub points: usize,
    /// Roll/pitch/yaw of `world_from_lidar` when the frame has a pose.
    pub pose: Option<RollPitchYaw>,
    pub ground: Option<GroundEstimate>,
    /// Why the ground fit found nothing (when it ran and failed).
    pub ground_failure: Option<String>,
    /// After temporal smoothing (frames of a sequence).
    pub smoothed: Option<SmoothedAttitude>,
    pub level_source: LevelSource,
}

/// One frame's contribution.
#[derive(Debug, Clone)]
pub struct FrameStats {
    pub stats: GroupStats,
    pub attitude: FrameAttitude,
    /// `(ρ m, θʳ deg)` of each object in the sensor frame.
    pub targets: Vec<[f64; 2]>,
}

#[derive(Debug, Clone, Serialize)]
pub struct SequenceStats {
    pub input: usize,
    pub platform: Platform,
    pub sequence: String,
    pub stats: GroupStats,
}

#[derive(Debug, Clone, Serialize)]
pub struct Analysis {
    pub inputs: Vec<InputSummary>,
    pub config: StatsConfig,
    pub total: GroupStats,
    pub platforms: BTreeMap<Platform, GroupStats>,
    /// Keyed `platform/sequence` (with `#input` appended when two inputs share a name).
    pub sequences: BTreeMap<String, SequenceStats>,
    /// `(ρ m, θʳ deg)` samples per platform (sensor frame), for scatter plots.
    pub target_samples: BTreeMap<Platform, Reservoir<[f64; 2]>>,
}

/// Progress reports from the pipeline (called from worker threads).
pub trait Progress: Sync {
    fn total(&self, _frames: u64) {}
    fn frame_done(&self) {}
}

/// No progress reporting.
pub struct NoProgress;
impl Progress for NoProgress {}

/// Intensity as a [0, 1] reflectivity: nuScenes stores 0–255.
pub fn intensity_scale(format: Format) -> f64 {
    match format {
        Format::Nuscenes => 1.0 / 255.0,
        Format::Pi3det | Format::Kitti => 1.0,
    }
}

/// Statistics of a single frame (hand-built frames in tests, or one step of [`analyze`]).
pub fn frame_stats(frame: &Frame, config: &StatsConfig, intensity_scale: f64) -> FrameStats {
    let info = &frame.info;
    let mut stats = GroupStats::new(config.bins, config.bins_2d);
    stats.frames = 1;
    let pose = info.world_from_lidar.as_ref().map(|p| p.roll_pitch_yaw());
    if let Some(rpy) = &pose {
        stats.ego.add_attitude(rpy);
    }
    let (ground, ground_failure) = match &config.ground {
        Some(g) => match estimate_ground(frame.points.xyz_f64(), g) {
            Ok(e) => (Some(e), None),
            Err(e) => (None, Some(e.to_string())),
        },
        None => (None, None),
    };
    if config.ground.is_some() {
        stats.ground.add(ground.as_ref(), pose.as_ref());
    }
    let from_pose = pose.map(|p| (level_from_sensor(p), LevelSource::Pose));
    let from_ground = ground.map(|g| (g.level_from_lidar(), LevelSource::Ground));
    let (level, level_source) = match config.level {
        LevelChoice::Auto => from_pose.or(from_ground),
        LevelChoice::Pose => from_pose,
        LevelChoice::Ground => from_ground,
        LevelChoice::Sensor => None,
    }
    .unwrap_or((UnitQuaternion::identity(), LevelSource::Sensor));
    stats.elevation.add_frame(frame.points.xyz_f64(), &level, level_source);
    let identity = UnitQuaternion::identity();
    let targets = info
        .objects
        .iter()
        .map(|o| {
            stats.targets_level.add_box(&o.box3d, &level);
            let (rho, theta) = stats.targets.add_box(&o.box3d, &identity);
            [rho, theta]
        })
        .collect();
    stats.boxes.add_frame(&info.objects, &frame.points_per_object());
    stats.points.add_cloud(&frame.points, intensity_scale);
    let attitude = FrameAttitude {
        input: 0,
        frame_id: info.id.clone(),
        platform: info.platform,
        sequence: info.sequence.clone(),
        timestamp_s: info.timestamp_s,
        points: frame.points.len(),
        pose,
        ground,
        ground_failure,
        smoothed: None,
        level_source,
    };
    FrameStats { stats, attitude, targets }
}

/// A frame's place in the processing order.
#[derive(Debug, Clone)]
struct FrameKey {
    input: usize,
    index: usize,
    sequence: Option<String>,
}

/// Frames of one input in processing order: sequences by name, frames by time (index when a
/// timestamp is missing); frames outside any sequence last, in index order.
fn order_frames(
    input: usize,
    dataset: &dyn Dataset,
    max_frames: Option<usize>,
) -> Result<Vec<FrameKey>, AnalysisError> {
    let mut rows = (0..dataset.len())
        .into_par_iter()
        .map(|i| dataset.info(i).map(|f| (f.sequence, f.timestamp_s, i)))
        .collect::<Result<Vec<_>, _>>()?;
    rows.sort_by(|a, b| {
        let seq = |s: &Option<String>| (s.is_none(), s.clone());
        seq(&a.0).cmp(&seq(&b.0)).then(a.1.unwrap_or(f64::NAN).total_cmp(&b.1.unwrap_or(f64::NAN))).then(a.2.cmp(&b.2))
    });
    rows.truncate(max_frames.unwrap_or(usize::MAX));
    Ok(rows.into_iter().map(|(sequence, _, index)| FrameKey { input, index, sequence }).collect())
}

/// The frames of the sequence being folded, kept until the sequence ends for smoothing.
struct Run {
    input: usize,
    sequence: Option<String>,
    frames: Vec<FrameAttitude>,
}

struct Folder<'c> {
    config: &'c StatsConfig,
    total: GroupStats,
    platforms: BTreeMap<Platform, GroupStats>,
    sequences: BTreeMap<String, SequenceStats>,
    target_samples: BTreeMap<Platform, Reservoir<[f64; 2]>>,
    run: Option<Run>,
}

impl Folder<'_> {
    fn sequence_key(&self, input: usize, platform: Platform, sequence: &str) -> String {
        let key = format!("{platform}/{sequence}");
        match self.sequences.get(&key) {
            Some(s) if s.input != input => format!("{key}#{input}"),
            _ => key,
        }
    }

    fn new_group(&self) -> GroupStats {
        GroupStats::new(self.config.bins, self.config.bins_2d)
    }

    /// The groups a frame belongs to: overall, its platform, its sequence.
    fn groups(&mut self, input: usize, platform: Platform, sequence: Option<&str>) -> Vec<&mut GroupStats> {
        let seq_key = sequence.map(|s| self.sequence_key(input, platform, s));
        let fresh = self.new_group();
        if let (Some(key), Some(seq)) = (&seq_key, sequence) {
            self.sequences.entry(key.clone()).or_insert_with(|| SequenceStats {
                input,
                platform,
                sequence: seq.to_string(),
                stats: fresh.clone(),
            });
        }
        let mut out = vec![&mut self.total];
        out.push(self.platforms.entry(platform).or_insert(fresh));
        if let Some(key) = seq_key {
            out.push(&mut self.sequences.get_mut(&key).expect("inserted above").stats);
        }
        out
    }

    fn add(
        &mut self,
        mut f: FrameStats,
        emit: &mut dyn FnMut(&FrameAttitude) -> Result<(), AnalysisError>,
    ) -> Result<(), AnalysisError> {
        let a = &f.attitude;
        let same_run =
            self.run.as_ref().is_some_and(|r| r.input == a.input && r.sequence.is_some() && r.sequence == a.sequence);
        if !same_run {
            self.flush(emit)?;
            self.run = Some(Run { input: a.input, sequence: a.sequence.clone(), frames: Vec::new() });
        }
        let previous_pose = self.run.as_ref().and_then(|r| r.frames.last()).and_then(|p| p.pose);
        if let (Some(prev), Some(cur)) = (previous_pose, a.pose) {
            f.stats.ego.add_step(&prev, &cur);
        }
        let (input, platform, sequence) = (a.input, a.platform, a.sequence.clone());
        for g in self.groups(input, platform, sequence.as_deref()) {
            g.merge(&f.stats)?;
        }
        let samples = self
            .target_samples
            .entry(platform)
            .or_insert_with(|| Reservoir::new(self.config.scatter_samples, self.config.seed ^ platform as u64));
        f.targets.into_iter().for_each(|t| samples.push(t));
        self.run.as_mut().expect("started above").frames.push(f.attitude);
        Ok(())
    }

    /// Ends the current run: smooths its ground attitude and hands its frames out.
    fn flush(
        &mut self,
        emit: &mut dyn FnMut(&FrameAttitude) -> Result<(), AnalysisError>,
    ) -> Result<(), AnalysisError> {
        let Some(mut run) = self.run.take() else { return Ok(()) };
        if let (Some(seq), true, true) = (&run.sequence, self.config.smooth, self.config.ground.is_some()) {
            let platform = run.frames[0].platform;
            let stamps: Vec<Option<f64>> = run.frames.iter().map(|f| f.timestamp_s).collect();
            let smoothing = SmoothingConfig::for_platform(platform);
            let times = sequence_times(&stamps, smoothing.default_dt_s);
            let estimates: Vec<Option<GroundEstimate>> = run.frames.iter().map(|f| f.ground).collect();
            let smoothed = smooth_sequence(&times, &estimates, &smoothing);
            let seq = seq.clone();
            for (frame, s) in run.frames.iter_mut().zip(smoothed) {
                frame.smoothed = Some(s);
                if let Some(pose) = frame.pose {
                    for g in self.groups(run.input, platform, Some(&seq)) {
                        g.ground.add_smoothed(&s, &pose);
                    }
                }
            }
        }
        run.frames.iter().try_for_each(emit)
    }
}

/// Analyses the inputs. `emit` receives every frame's attitude row in processing order (write
/// them out as they come; they are not kept).
pub fn analyze(
    inputs: &[Input<'_>],
    config: &StatsConfig,
    progress: &dyn Progress,
    emit: &mut dyn FnMut(&FrameAttitude) -> Result<(), AnalysisError>,
) -> Result<Analysis, AnalysisError> {
    if config.bins == 0 || config.bins_2d == 0 {
        return Err(AnalysisError::Invalid("bins must be at least 1".into()));
    }
    let mut keys = Vec::new();
    let mut summaries = Vec::new();
    for (i, input) in inputs.iter().enumerate() {
        let k = order_frames(i, input.dataset, config.max_frames)?;
        summaries.push(InputSummary {
            name: input.name.clone(),
            format: input.dataset.format(),
            frames_total: input.dataset.len(),
            frames_used: k.len(),
        });
        keys.extend(k);
    }
    progress.total(keys.len() as u64);
    let mut folder = Folder {
        config,
        total: GroupStats::new(config.bins, config.bins_2d),
        platforms: BTreeMap::new(),
        sequences: BTreeMap::new(),
        target_samples: BTreeMap::new(),
        run: None,
    };
    for chunk in keys.chunks(config.chunk_frames.max(1)) {
        let done = chunk
            .par_iter()
            .map(|k| {
                let input = &inputs[k.input];
                let frame = input.dataset.load(k.index)?;
                let mut f = frame_stats(&frame, config, intensity_scale(input.dataset.format()));
                f.attitude.input = k.input;
                // The order key's sequence is the one folded on (same as the info's).
                f.attitude.sequence = k.sequence.clone();
                progress.frame_done();
                Ok(f)
            })
            .collect::<Result<Vec<_>, AnalysisError>>()?;
        for f in done {
            folder.add(f, emit)?;
        }
    }
    folder.flush(emit)?;
    Ok(Analysis {
        inputs: summaries,
        config: config.clone(),
        total: folder.total,
        platforms: folder.platforms,
        sequences: folder.sequences,
        target_samples: folder.target_samples,
    })
}
