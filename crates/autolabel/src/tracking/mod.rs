//! 3-D multi-object tracking of labels over a dataset's sequences (`pi3det track`): boxes go to
//! the world frame through each frame's `world_from_lidar` (identity for pose-free data), are
//! tracked per class ([`tracker`]) and come back to the LiDAR frame with their track ids.

pub mod config;
pub mod giou;
pub mod kalman;
pub mod refine;
pub mod tracker;

use std::collections::BTreeMap;

use pi3det_data::{FrameInfo, Object};
use pi3det_geometry::Pose;
use serde::Serialize;

pub use config::{StaticRefinement, TrackClass, TrackingConfig};
pub use tracker::{track_sequence, Track, TrackBox, TrackFrame};

use crate::labels::LabelSet;
use crate::AutolabelError;

/// Tracked labels: boxes per frame (LiDAR frame) and each box's track id, in the same order.
#[derive(Debug, Clone, Default)]
pub struct Tracked {
    pub labels: LabelSet,
    pub track_ids: BTreeMap<String, Vec<u64>>,
    pub stats: TrackingStats,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TrackingStats {
    pub sequences: usize,
    pub frames: usize,
    pub input_boxes: usize,
    pub tracks: usize,
    pub static_tracks: usize,
    pub observed_boxes: usize,
    pub interpolated_boxes: usize,
}

/// Tracks `labels` over the frames `infos` (a dataset's, any order). Frames are grouped by
/// sequence (frames without one form a single sequence) and ordered by timestamp; without
/// timestamps `frame_rate_hz` spaces them by frame-id order, and without that it is an error.
/// Labels for frames not in `infos` are an error naming the label file.
pub fn track_dataset(
    infos: &[FrameInfo],
    labels: &LabelSet,
    cfg: &TrackingConfig,
    frame_rate_hz: Option<f64>,
) -> Result<Tracked, AutolabelError> {
    cfg.validate()?;
    if let Some(hz) = frame_rate_hz.filter(|hz| !(hz.is_finite() && *hz > 0.0)) {
        return Err(AutolabelError::Input(format!("frame rate {hz} Hz: must be a positive number")));
    }
    labels.check_frames(infos.iter().map(|i| i.id.as_str()))?;
    let mut sequences: BTreeMap<String, Vec<&FrameInfo>> = BTreeMap::new();
    for info in infos {
        sequences.entry(info.sequence.clone().unwrap_or_default()).or_default().push(info);
    }
    let mut out = Tracked::default();
    let mut next_id = 0u64;
    for (name, mut frames) in sequences {
        let stamps: Option<Vec<f64>> = frames.iter().map(|f| f.timestamp_s).collect();
        let times = match (stamps, frame_rate_hz) {
            (Some(_), _) => {
                frames.sort_by(|a, b| a.timestamp_s.unwrap_or(0.0).total_cmp(&b.timestamp_s.unwrap_or(0.0)));
                frames.iter().map(|f| f.timestamp_s.unwrap_or(0.0)).collect::<Vec<_>>()
            }
            (None, Some(hz)) => {
                frames.sort_by(|a, b| a.id.cmp(&b.id));
                (0..frames.len()).map(|i| i as f64 / hz).collect()
            }
            _ => {
                let missing = frames.iter().find(|f| f.timestamp_s.is_none()).map_or("", |f| f.id.as_str());
                return Err(AutolabelError::Input(format!(
                    "sequence {name:?}: frame {missing} has no timestamp; pass a frame rate (--frame-rate HZ) to space frames by id"
                )));
            }
        };
        let track_frames: Vec<TrackFrame> = frames
            .iter()
            .zip(&times)
            .map(|(f, &t)| TrackFrame {
                frame_id: f.id.clone(),
                timestamp_s: t,
                world_from_lidar: f.world_from_lidar.unwrap_or_else(Pose::identity),
                detections: labels.frames.get(&f.id).cloned().unwrap_or_default(),
            })
            .collect();
        out.stats.sequences += 1;
        out.stats.frames += track_frames.len();
        out.stats.input_boxes += track_frames.iter().map(|f| f.detections.len()).sum::<usize>();
        let tracks = track_sequence(&track_frames, cfg, &mut next_id);
        for f in &track_frames {
            out.labels.frames.entry(f.frame_id.clone()).or_default();
            out.track_ids.entry(f.frame_id.clone()).or_default();
        }
        for t in &tracks {
            out.stats.tracks += 1;
            out.stats.static_tracks += usize::from(t.is_static);
            for b in &t.boxes {
                let f = &track_frames[b.frame];
                let mut o = Object::new(t.class.clone(), b.box3d.transformed(&f.world_from_lidar.inverse()));
                o.score = Some(b.score);
                out.labels.frames.get_mut(&f.frame_id).expect("frame entry").push(o);
                out.track_ids.get_mut(&f.frame_id).expect("frame entry").push(t.id);
                if b.observed {
                    out.stats.observed_boxes += 1;
                } else {
                    out.stats.interpolated_boxes += 1;
                }
            }
        }
    }
    Ok(out)
}
