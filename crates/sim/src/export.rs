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
    /// Force one layout on every sequence (wins over `stratify_layouts`).
    pub layout: Option<Layout>,
    /// Give each split's sequences layouts in the platform's proportions, in a fixed interleaved
    /// order ([`stratified_layouts`]), instead of drawing each: a small validation split then holds
    /// the intended mix whatever the seed (12 drawn vehicle sequences held 2 to 6 suburban ones).
    pub stratify_layouts: bool,
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
    let mut report = ExportReport::default();
    for plan in plans {
        for split in ["train", "val"] {
            report.splits.extend(export_split(cfg, plan, split, opts, on_frame)?);
        }
    }
    Ok(report)
}

/// Renders and writes one split of a plan (`None` when the plan puts no sequence in it). A
/// sequence depends only on the seed, the platform and its index, so the two splits of a plan can
/// be written with different seeds: a validation split that stays fixed while the training seed
/// changes.
pub fn export_split(
    cfg: &SimConfig,
    plan: &PlatformPlan,
    split: &str,
    opts: &ExportOptions,
    on_frame: &mut dyn FnMut(&Sequence, &SimFrame),
) -> Result<Option<WrittenSplit>, SimError> {
    cfg.validate()?;
    let pc = cfg.platform(plan.platform)?;
    if plan.frames > 9999 {
        return Err(SimError::invalid("at most 9999 frames per sequence"));
    }
    if plan.val_sequences > plan.sequences {
        return Err(SimError::invalid("more validation sequences than sequences"));
    }
    if split != "train" && split != "val" {
        return Err(SimError::invalid(format!("split must be train or val, not {split:?}")));
    }
    let indices: Vec<u32> = (0..plan.sequences).filter(|&i| plan.split_of(i) == split).collect();
    if indices.is_empty() {
        return Ok(None);
    }
    let layouts: Vec<Option<Layout>> = match (opts.layout, opts.stratify_layouts) {
        (Some(l), _) => vec![Some(l); indices.len()],
        (None, true) => stratified_layouts(pc.layout_weights, indices.len()).into_iter().map(Some).collect(),
        (None, false) => vec![None; indices.len()],
    };
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
    for (index, layout) in indices.into_iter().zip(layouts) {
        let spec = SequenceSpec { platform: plan.platform, index, frames: plan.frames, seed: opts.seed, layout };
        let seq = Sequence::generate(&cfg.for_sequence(opts.seed, index)?, spec)?;
        tracing::info!(
            "{}: {} frames, {} actors, {} static objects, {}",
            seq.name,
            seq.len(),
            seq.actor_count(),
            seq.scene.object_count(),
            seq.sensor().name
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
    Ok(Some(written))
}

/// `n` layouts in the proportions of `weights` (urban, suburban, park), interleaved by smooth
/// weighted round robin: every prefix is within one sequence of its share, so a split truncated to
/// its first sequences keeps the mix too.
pub fn stratified_layouts(weights: [f64; 3], n: usize) -> Vec<Layout> {
    let total: f64 = weights.iter().map(|w| w.max(0.0)).sum();
    let share = weights.map(|w| if total > 0.0 { w.max(0.0) / total } else { 1.0 / 3.0 });
    let mut credit = [0.0f64; 3];
    (0..n)
        .map(|_| {
            for (c, s) in credit.iter_mut().zip(share) {
                *c += s;
            }
            // Ties go to the earlier layout; a zero share never wins over a positive one.
            let k = (0..3).filter(|&k| share[k] > 0.0).fold(None, |best: Option<usize>, k| match best {
                Some(b) if credit[b] >= credit[k] => Some(b),
                _ => Some(k),
            });
            let k = k.unwrap_or(0);
            credit[k] -= 1.0;
            Layout::ALL[k]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counts(ls: &[Layout]) -> [usize; 3] {
        let mut c = [0; 3];
        for l in ls {
            c[Layout::ALL.iter().position(|a| a == l).unwrap()] += 1;
        }
        c
    }

    #[test]
    fn stratified_layouts_keep_the_weights_in_every_prefix() {
        for weights in [[0.55, 0.45, 0.0], [0.45, 0.35, 0.2], [0.2, 0.4, 0.4], [1.0, 0.0, 0.0]] {
            let total: f64 = weights.iter().sum();
            let all = stratified_layouts(weights, 40);
            for n in 1..=all.len() {
                let c = counts(&all[..n]);
                for k in 0..3 {
                    let want = n as f64 * weights[k] / total;
                    assert!((c[k] as f64 - want).abs() <= 1.0, "{weights:?}, first {n}: {c:?} vs {want}");
                    if weights[k] == 0.0 {
                        assert_eq!(c[k], 0, "a layout of weight 0 never appears");
                    }
                }
            }
            assert_eq!(stratified_layouts(weights, 40), all, "deterministic");
        }
        // The vehicle's 12 validation sequences: 7 urban, 5 suburban, never 2 or 6 suburban.
        assert_eq!(counts(&stratified_layouts([0.55, 0.45, 0.0], 12)), [7, 5, 0]);
        assert!(stratified_layouts([0.0; 3], 3).len() == 3, "degenerate weights still give n layouts");
    }
}
