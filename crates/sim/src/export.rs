//! Datasets in the Pi3DET layout: sequences rendered and written through `pi3det-data`'s writer,
//! one root per platform and split, split by sequence (never by frame).

use std::path::PathBuf;

use pi3det_data::pi3det::Pi3detWriter;
use pi3det_data::Platform;

use crate::config::SimConfig;
use crate::scene::Layout;
use crate::sequence::{Sequence, SequenceSpec, SimFrame};
use crate::SimError;

/// How many sequences and frames to make for one platform.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlatformPlan {
    pub platform: Platform,
    pub sequences: u32,
    pub frames: u32,
    /// The last `val_sequences` sequences go to the `val` split, the others to `train`.
    pub val_sequences: u32,
}

impl PlatformPlan {
    /// A plan with the default split: a quarter of the sequences (at least one when there are two
    /// or more) for validation.
    pub fn new(platform: Platform, sequences: u32, frames: u32) -> Self {
        Self { platform, sequences, frames, val_sequences: default_val_sequences(sequences) }
    }

    pub fn split_of(&self, index: u32) -> &'static str {
        if index + self.val_sequences >= self.sequences {
            "val"
        } else {
            "train"
        }
    }
}

pub fn default_val_sequences(sequences: u32) -> u32 {
    if sequences < 2 {
        0
    } else {
        ((sequences as f64 / 4.0).round() as u32).max(1)
    }
}

/// `pi3det-mini`: all three platforms at small scale with the paper's proportions of frames
/// (vehicle 32,193 : quadruped 12,300 : drone 7,052 ≈ 1 : 0.38 : 0.22) and its near-even
/// train/val split by sequence.
pub fn pi3det_mini() -> Vec<PlatformPlan> {
    vec![
        PlatformPlan { platform: Platform::Vehicle, sequences: 4, frames: 50, val_sequences: 2 },
        PlatformPlan { platform: Platform::Quadruped, sequences: 4, frames: 19, val_sequences: 2 },
        PlatformPlan { platform: Platform::Drone, sequences: 4, frames: 11, val_sequences: 2 },
    ]
}

#[derive(Debug, Clone, PartialEq)]
pub struct ExportOptions {
    pub out: PathBuf,
    pub seed: u64,
    pub overwrite: bool,
    /// Put each platform in its own subfolder (`out/<platform>/<split>`); otherwise `out/<split>`.
    pub per_platform_folders: bool,
    pub layout: Option<Layout>,
}

/// What was written for one platform and split.
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenSplit {
    pub platform: Platform,
    pub split: String,
    pub root: PathBuf,
    pub info_file: PathBuf,
    pub sequences: Vec<String>,
    pub frames: usize,
    pub boxes: usize,
    pub points: usize,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct ExportReport {
    pub splits: Vec<WrittenSplit>,
}

impl ExportReport {
    pub fn frames(&self) -> usize {
        self.splits.iter().map(|s| s.frames).sum()
    }
}

/// The folder of one platform's split.
pub fn split_root(opts: &ExportOptions, platform: Platform, split: &str) -> PathBuf {
    if opts.per_platform_folders {
        opts.out.join(platform.as_str()).join(split)
    } else {
        opts.out.join(split)
    }
}

/// The frame id: sequence index then frame index, seven digits like the released files.
pub fn frame_id(sequence_index: u32, frame: usize) -> String {
    format!("{sequence_index:03}{frame:04}")
}

/// Renders and writes every plan. `on_frame` sees each frame after it is written (progress).
pub fn export(
    cfg: &SimConfig,
    plans: &[PlatformPlan],
    opts: &ExportOptions,
    on_frame: &mut dyn FnMut(&Sequence, &SimFrame),
) -> Result<ExportReport, SimError> {
    cfg.validate()?;
    let mut report = ExportReport::default();
    for plan in plans {
        cfg.platform(plan.platform)?;
        if plan.frames > 9999 {
            return Err(SimError::invalid("at most 9999 frames per sequence"));
        }
        if plan.val_sequences > plan.sequences {
            return Err(SimError::invalid("more validation sequences than sequences"));
        }
        for split in ["train", "val"] {
            let indices: Vec<u32> = (0..plan.sequences).filter(|&i| plan.split_of(i) == split).collect();
            if indices.is_empty() {
                continue;
            }
            let root = split_root(opts, plan.platform, split);
            let mut writer = Pi3detWriter::create(&root, split, opts.overwrite)?;
            let mut written = WrittenSplit {
                platform: plan.platform,
                split: split.to_string(),
                root: root.clone(),
                info_file: PathBuf::new(),
                sequences: Vec::new(),
                frames: 0,
                boxes: 0,
                points: 0,
            };
            for index in indices {
                let spec = SequenceSpec {
                    platform: plan.platform,
                    index,
                    frames: plan.frames,
                    seed: opts.seed,
                    layout: opts.layout,
                };
                let seq = Sequence::generate(cfg, spec)?;
                tracing::info!(
                    "{}: {} frames, {} actors, {} static objects",
                    seq.name,
                    seq.len(),
                    seq.actor_count(),
                    seq.scene.object_count()
                );
                for f in 0..seq.len() {
                    let sim = seq.render(f);
                    let frame = sim.to_frame(&frame_id(index, f), plan.platform, &seq.name);
                    writer.write_frame(&frame)?;
                    written.frames += 1;
                    written.boxes += sim.objects.len();
                    written.points += sim.points.len();
                    on_frame(&seq, &sim);
                }
                written.sequences.push(seq.name.clone());
            }
            written.info_file = writer.finish()?;
            report.splits.push(written);
        }
    }
    Ok(report)
}
