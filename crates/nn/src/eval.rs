//! Evaluation of detections with the project's KITTI-protocol evaluator (`pi3det-eval`), and the
//! short summary training logs and the demo table use (R40 at moderate difficulty, strict IoU:
//! Car 0.7, Pedestrian 0.5).

pub use pi3det_eval::summary::{summarize, ApSummary, ClassAp, LooseAp};
pub use pi3det_eval::{format_breakdown, Breakdown};
use pi3det_eval::{Detections, EvalOptions, EvalReport};

use crate::detect::FrameDetections;
use crate::error::{NnError, Result};

/// Options for the detector's evaluation: its classes; ground truth and detections restricted to
/// the BEV range the detector sees (`bev_range`), so a ±40 m model is not charged for objects at
/// 90 m.
pub fn options(classes: &[String], bev_range: Option<[f64; 4]>, score_threshold: Option<f64>) -> EvalOptions {
    EvalOptions {
        classes: classes.to_vec(),
        bev_range,
        score_threshold,
        per_platform: true,
        per_sequence: false,
        ..EvalOptions::default()
    }
}

/// KITTI annotates only what its left colour camera sees, and the field detects on the points in
/// that view (OpenPCDet's `FOV_POINTS_ONLY`): a detection on a full KITTI scan whose centre falls
/// outside the image would count as a false positive against objects nobody labelled. Unless some
/// ground-truth box of the frames with KITTI calibration lies behind the camera or well beside its
/// image (data in KITTI's format labelled beyond the view, as Argoverse's converter writes), drops
/// the detections outside the image from those frames and returns how many.
pub fn keep_camera_view(frames: &mut [FrameDetections]) -> usize {
    /// The box centre in the camera's pixels (`None` behind it) and the image size, for frames
    /// with KITTI calibration.
    fn pixel(info: &pi3det_data::FrameInfo, b: &pi3det_geometry::Box3d) -> Option<(Option<[f64; 2]>, [f64; 2])> {
        let Some(pi3det_data::Calib::Kitti(calib)) = &info.calib else { return None };
        let [w, h] = info.cameras.first().and_then(|c| c.image_size).unwrap_or([1242, 375]);
        let rect = calib.lidar_to_rect([b.x, b.y, b.z]);
        let uv = if rect[2] > 0.0 { calib.rect_to_image(rect) } else { None };
        Some((uv, [f64::from(w), f64::from(h)]))
    }
    // Inside the image grown by `margin` of its size on every side.
    let inside = |(uv, [w, h]): (Option<[f64; 2]>, [f64; 2]), margin: f64| {
        uv.is_some_and(|[u, v]| {
            (-margin * w..(1.0 + margin) * w).contains(&u) && (-margin * h..(1.0 + margin) * h).contains(&v)
        })
    };
    // Truncated objects at the image's edge have their centre just outside it; an object behind
    // the camera or well beside the image is what says the labels go beyond the view.
    let labels_beyond_view =
        frames.iter().any(|f| f.info.objects.iter().any(|o| pixel(&f.info, &o.box3d).is_some_and(|p| !inside(p, 0.5))));
    if labels_beyond_view {
        return 0;
    }
    let mut dropped = 0;
    for f in frames.iter_mut() {
        let before = f.objects.len();
        let info = &f.info;
        f.objects.retain(|o| pixel(info, &o.box3d).is_none_or(|p| inside(p, 0.0)));
        dropped += before - f.objects.len();
    }
    dropped
}

/// The detections of `frames` in the evaluator's form.
pub fn detections(frames: &[FrameDetections]) -> Result<Detections> {
    Detections::from_objects(frames.iter().map(|f| (f.info.id.clone(), f.objects.clone()))).map_err(NnError::from)
}

/// Evaluates detections against their frames' ground truth.
pub fn evaluate(frames: &[FrameDetections], opts: &EvalOptions) -> Result<(EvalReport, ApSummary)> {
    let dets = detections(frames)?;
    let gt: Vec<pi3det_data::FrameInfo> = frames.iter().map(|f| f.info.clone()).collect();
    let report = pi3det_eval::evaluate(&gt, &dets, opts).map_err(NnError::from)?;
    let summary = summarize(&report);
    Ok((report, summary))
}

/// The error breakdown (AP and recall by distance and points per box, found-but-misplaced share,
/// localisation errors) of detections against their frames' ground truth.
pub fn breakdown(frames: &[FrameDetections], opts: &EvalOptions) -> Result<Breakdown> {
    let dets = detections(frames)?;
    let gt: Vec<pi3det_data::FrameInfo> = frames.iter().map(|f| f.info.clone()).collect();
    pi3det_eval::breakdown(&gt, &dets, opts).map_err(NnError::from)
}
