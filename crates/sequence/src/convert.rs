//! Sequences → the released Pi3DET layout (`training/point_cloud/<id>.bin` + one
//! `pi3det_infos_<split>.pkl` with platform, sequence, timestamp, pose and boxes per frame), so
//! every pi3det command runs on them.

use std::path::{Path, PathBuf};
use std::time::Instant;

use pi3det_data::pi3det::Pi3detWriter;
use pi3det_data::{DataError, Dataset};
use rayon::prelude::*;

#[derive(Debug, Clone)]
pub struct ConvertOptions {
    pub split: String,
    pub overwrite: bool,
}

impl Default for ConvertOptions {
    fn default() -> Self {
        Self { split: "train".into(), overwrite: false }
    }
}

#[derive(Debug, Clone)]
pub struct ConvertReport {
    pub frames: usize,
    pub points: usize,
    pub info_path: PathBuf,
    pub seconds: f64,
}

/// Writes every frame of `datasets` into `out`. Frames are decoded in parallel a batch at a time
/// and written in order; an existing info file or point file is an error unless `overwrite`.
/// Points keep x, y, z, intensity (the released layout's four channels).
pub fn to_pi3det_layout(
    datasets: &[&dyn Dataset],
    out: &Path,
    options: &ConvertOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<ConvertReport, DataError> {
    let start = Instant::now();
    let mut writer = Pi3detWriter::create(out, &options.split, options.overwrite)?;
    let total: usize = datasets.iter().map(|d| d.len()).sum();
    let batch = 4 * rayon::current_num_threads().max(1);
    let (mut frames, mut points) = (0, 0);
    for ds in datasets {
        for first in (0..ds.len()).step_by(batch) {
            let loaded: Vec<_> = (first..(first + batch).min(ds.len())).into_par_iter().map(|i| ds.load(i)).collect();
            for frame in loaded {
                let frame = frame?;
                points += frame.points.len();
                writer.write_frame(&frame)?;
                frames += 1;
            }
            progress(frames, total);
        }
    }
    let info_path = writer.finish()?;
    Ok(ConvertReport { frames, points, info_path, seconds: start.elapsed().as_secs_f64() })
}
