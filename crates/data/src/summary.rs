//! Dataset statistics as the paper tabulates them (appendix Table 6): frames, points, boxes per
//! class, broken down per platform and per sequence. Frames are streamed in parallel; only counts
//! are kept, so memory does not grow with the dataset.

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::Serialize;

use crate::dataset::Dataset;
use crate::error::DataError;
use crate::frame::Frame;

/// Counts for one group of frames.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Counts {
    pub frames: usize,
    pub points: u64,
    pub dropped_points: u64,
    pub boxes_per_class: BTreeMap<String, usize>,
}

impl Counts {
    fn add(&mut self, other: &Counts) {
        self.frames += other.frames;
        self.points += other.points;
        self.dropped_points += other.dropped_points;
        for (k, v) in &other.boxes_per_class {
            *self.boxes_per_class.entry(k.clone()).or_default() += v;
        }
    }

    pub fn boxes(&self) -> usize {
        self.boxes_per_class.values().sum()
    }
}

/// One box and the number of points inside it (inclusive test on the frame's points).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoxPoints {
    pub frame_id: String,
    pub class: String,
    pub points: usize,
    /// The count the dataset itself stored, when it has one.
    pub stored_points: Option<u32>,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Summary {
    pub format: String,
    pub total: Counts,
    pub per_platform: BTreeMap<String, Counts>,
    pub per_sequence: BTreeMap<String, Counts>,
    pub per_box: Vec<BoxPoints>,
}

struct FrameStats {
    platform: String,
    sequence: Option<String>,
    counts: Counts,
    boxes: Vec<BoxPoints>,
}

fn frame_stats(frame: &Frame, dropped: usize, per_box: bool) -> FrameStats {
    let info = &frame.info;
    let mut counts =
        Counts { frames: 1, points: frame.points.len() as u64, dropped_points: dropped as u64, ..Default::default() };
    for o in &info.objects {
        *counts.boxes_per_class.entry(o.name.clone()).or_default() += 1;
    }
    let boxes = if per_box {
        frame
            .points_per_object()
            .into_iter()
            .zip(&info.objects)
            .map(|(points, o)| BoxPoints {
                frame_id: info.id.clone(),
                class: o.name.clone(),
                points,
                stored_points: o.num_points,
            })
            .collect()
    } else {
        Vec::new()
    };
    FrameStats { platform: info.platform.to_string(), sequence: info.sequence.clone(), counts, boxes }
}

/// Summarises a dataset; `per_box` also counts the points inside every box.
/// `progress` is called once per frame (from worker threads).
pub fn summarize(dataset: &dyn Dataset, per_box: bool, progress: &(dyn Fn() + Sync)) -> Result<Summary, DataError> {
    let stats: Vec<FrameStats> = (0..dataset.len())
        .into_par_iter()
        .map(|i| {
            let info = dataset.info(i)?;
            // Datasets whose points are not `.bin` files (the sequence release's HDF5 packets)
            // decode them in `load`.
            let s = if info.points_path.extension().is_some_and(|e| e == "bin") {
                let channels: Vec<&str> = info.point_channels.iter().map(String::as_str).collect();
                let read = crate::points::read_bin(&info.points_path, &channels)?;
                frame_stats(&Frame { info, points: read.cloud }, read.dropped_non_finite, per_box)
            } else {
                frame_stats(&dataset.load(i)?, 0, per_box)
            };
            progress();
            Ok(s)
        })
        .collect::<Result<_, DataError>>()?;
    let mut summary = Summary { format: format!("{:?}", dataset.format()).to_lowercase(), ..Default::default() };
    for s in stats {
        summary.total.add(&s.counts);
        summary.per_platform.entry(s.platform).or_default().add(&s.counts);
        if let Some(seq) = s.sequence {
            summary.per_sequence.entry(seq).or_default().add(&s.counts);
        }
        summary.per_box.extend(s.boxes);
    }
    Ok(summary)
}
