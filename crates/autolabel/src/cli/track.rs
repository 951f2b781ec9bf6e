//! `pi3det track`: tracking of a label file over a dataset's sequences.

use std::path::PathBuf;
use std::time::Instant;

use super::{config_or_print, refuse_existing};
use crate::labels::LabelSet;
use crate::read_infos;
use crate::tracking::{track_dataset, TrackingConfig};
use crate::AutolabelError;

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

pub fn run(args: &TrackArgs) -> Result<(), AutolabelError> {
    let Some(cfg) = config_or_print(args.config.as_deref(), TrackingConfig::from_file, args.print_config)? else {
        return Ok(());
    };
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
