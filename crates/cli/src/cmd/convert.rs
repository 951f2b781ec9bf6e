//! `pi3det convert SEQUENCES... --to pi3det-layout --out DIR`: the full sequence release (or any
//! dataset pi3det reads) written in the released Pi3DET layout, which every command reads.

use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use pi3det_sequence::convert::{to_pi3det_layout, ConvertOptions};
use pi3det_sequence::{LabelFrame, SequenceOptions};

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Target {
    /// `training/point_cloud/<id>.bin` + `pi3det_infos_<split>.pkl`.
    Pi3detLayout,
}

#[derive(clap::Args)]
pub struct ConvertArgs {
    /// Sequence folders, or folders above them (`processed/`, `processed/Car`, ...); any other
    /// dataset pi3det reads is converted too.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    #[arg(long, value_enum)]
    pub to: Target,
    #[arg(long)]
    pub out: PathBuf,
    /// Replace files already in --out.
    #[arg(long)]
    pub overwrite: bool,
    /// The info file's split name (pi3det_infos_<split>.pkl).
    #[arg(long, default_value = "train")]
    pub split: String,
    /// Read the frames every file of a sequence has, when the pose file or ts_start is shorter
    /// than the data (the public loader does this silently); without it that is an error.
    #[arg(long)]
    pub truncate: bool,
    /// Frame of the pseudo-label boxes: `release` (drone / quadruped boxes are in the levelled
    /// frame of the pose, as the public loader reads them) or `lidar` (as stored).
    #[arg(long, default_value = "release")]
    pub label_frame: LabelFrame,
}

pub fn sequence_options(truncate: bool, label_frame: LabelFrame) -> SequenceOptions {
    SequenceOptions { truncate, label_frame }
}

pub fn run(args: &ConvertArgs) -> anyhow::Result<()> {
    let Target::Pi3detLayout = args.to;
    let options = sequence_options(args.truncate, args.label_frame);
    let datasets = args
        .inputs
        .iter()
        .map(|p| pi3det_sequence::open(p, options).with_context(|| format!("opening {}", p.display())))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let refs: Vec<&dyn pi3det_data::Dataset> = datasets.iter().map(|d| d.as_ref()).collect();
    let total: usize = refs.iter().map(|d| d.len()).sum();
    let bar = ProgressBar::new(total as u64)
        .with_style(ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames").expect("valid template"))
        .with_message("converting");
    let convert = ConvertOptions { split: args.split.clone(), overwrite: args.overwrite };
    let report = to_pi3det_layout(&refs, &args.out, &convert, |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    println!(
        "{} frames, {:.2} M points -> {} ({:.1} s, {:.1} frames/s)",
        report.frames,
        report.points as f64 / 1e6,
        report.info_path.display(),
        report.seconds,
        report.frames as f64 / report.seconds.max(1e-9)
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct BenchSequenceArgs {
    /// A sequence folder or tree to time (default: a synthetic OS1-64 1024x10 sequence).
    pub path: Option<PathBuf>,
    /// Frames to time.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
}

pub fn run_bench(args: &BenchSequenceArgs) -> anyhow::Result<()> {
    let report = pi3det_sequence::bench::run(args.path.as_deref(), args.frames)?;
    println!("{report}");
    Ok(())
}
