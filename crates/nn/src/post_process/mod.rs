//! Post-processing of candidate boxes: score threshold and rotated NMS (OpenPCDet semantics;
//! per class or over all classes at once), then what acts on the boxes after NMS.
//!
//! | module | what |
//! | --- | --- |
//! | this module | score threshold, rotated NMS, candidates → detections |
//! | [`ground_fit`] | vertical fit: bottom on the local ground, top on the highest point |
//! | [`bev_fit`] | planar fit: heading and BEV centre from the visible faces |
//! | [`upright_check`] | small objects that do not look like a standing body are ranked down |
//! | [`tta`] | test-time augmentation: views → back to the frame → weighted box fusion |

pub mod bev_fit;
pub mod ground_fit;
pub mod tta;
pub mod upright_check;

use pi3det_geometry::{nms, Box3d, NmsConfig};
use tch::Kind;

use crate::config::PostConfig;
use crate::dense_heads::Candidates;

/// One detection in the detector's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    pub box3d: Box3d,
    pub score: f64,
    pub class: usize,
}

/// Candidates as detections (non-finite ones dropped, headings wrapped).
pub fn to_detections(c: &Candidates) -> Vec<Detection> {
    let b: Vec<f32> = Vec::try_from(c.boxes.to_kind(Kind::Float).reshape([-1])).unwrap_or_default();
    let s: Vec<f32> = Vec::try_from(c.scores.to_kind(Kind::Float)).unwrap_or_default();
    let l: Vec<i64> = Vec::try_from(c.labels.to_kind(Kind::Int64)).unwrap_or_default();
    (0..s.len().min(l.len()).min(b.len() / 7))
        .filter(|&k| b[k * 7..k * 7 + 7].iter().all(|v| v.is_finite()) && s[k].is_finite())
        .map(|k| {
            let a: [f64; 7] = std::array::from_fn(|j| b[k * 7 + j] as f64);
            Detection { box3d: Box3d::from_array(a).with_wrapped_heading(), score: s[k] as f64, class: l[k] as usize }
        })
        .collect()
}

/// Rotated NMS with the thresholds of `post` (`iou`, `pre_max`, `post_max`), per class when
/// `post.per_class_nms`; the result is sorted by score.
pub fn nms_detections(
    dets: &[Detection],
    post: &PostConfig,
    num_classes: usize,
    iou: f64,
    post_max: usize,
) -> Vec<Detection> {
    let cfg = NmsConfig {
        iou_threshold: iou,
        score_threshold: post.score_threshold,
        pre_max_size: post.nms_pre_max,
        post_max_size: post_max,
    };
    let run = |subset: &[Detection]| -> Vec<Detection> {
        let boxes: Vec<Box3d> = subset.iter().map(|d| d.box3d).collect();
        let scores: Vec<f64> = subset.iter().map(|d| d.score).collect();
        nms(&boxes, &scores, &cfg).into_iter().map(|k| subset[k]).collect()
    };
    if post.per_class_nms {
        let mut out: Vec<Detection> = (0..num_classes)
            .flat_map(|c| run(&dets.iter().copied().filter(|d| d.class == c).collect::<Vec<_>>()))
            .collect();
        out.sort_by(|a, b| b.score.total_cmp(&a.score));
        out.truncate(post_max);
        out
    } else {
        run(dets)
    }
}

/// The post-NMS fits to the points that `post` asks for, in place, frame by frame: first the
/// vertical fit ([`crate::post_process::ground_fit`]), then the planar one ([`crate::post_process::bev_fit`]), which needs
/// the fitted bottom to tell body points from ground, then the upright check
/// ([`crate::post_process::upright_check`]) on the fitted boxes, after which each frame is re-sorted by score.
/// `classes` are the detector's class names. Frames without a point index (prepared without a
/// fit) are left as they are.
pub fn fit_to_points(
    post: &PostConfig,
    classes: &[String],
    frames: &mut [Vec<Detection>],
    index: &[Option<ground_fit::PointIndex>],
    detector_from_lidar: &[pi3det_geometry::Pose],
) {
    // Per class index: the upright check's settings when it checks that class.
    let upright: Vec<_> =
        classes.iter().map(|c| post.upright_check.as_ref().filter(|u| u.classes.contains(c))).collect();
    for ((dets, idx), pose) in frames.iter_mut().zip(index).zip(detector_from_lidar) {
        let Some(idx) = idx else { continue };
        let sensor_xy = [pose.translation.x, pose.translation.y];
        for d in dets.iter_mut() {
            if let Some(g) = &post.ground_fit {
                d.box3d = ground_fit::fit_box(&d.box3d, idx, g).0;
            }
            if let Some(b) = &post.bev_fit {
                d.box3d = bev_fit::fit_box(&d.box3d, idx, sensor_xy, b).0;
            }
            if let Some(u) = upright.get(d.class).copied().flatten() {
                if upright_check::check_box(&d.box3d, idx, u).is_some() {
                    d.score *= u.score_factor;
                }
            }
        }
        if post.upright_check.is_some() {
            dets.sort_by(|a, b| b.score.total_cmp(&a.score));
        }
    }
}
