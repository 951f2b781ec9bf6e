//! Test-time augmentation (`[post.tta]`): the network also sees each frame mirrored and turned
//! about the vertical (the views training's world flip and rotation taught it), every view's
//! detections go back to the frame, and weighted box fusion
//! ([`pi3det_geometry::weighted_box_fusion`]) merges them per class after each view's box fits
//! (made in the frame, on its own points). A box
//! the views agree on is placed by their score-weighted mean and keeps its score; a box one view
//! alone saw keeps that view's share. Why it pays: the views' errors differ (a sparse car one
//! view misses another finds), averaging the views that agree places a box better than any one
//! view, and a false positive only one view makes falls down the ranking. Measured:
//! results/2026-12-05-tta.md.
//!
//! The views run as one batch (frame-major: a frame's views are neighbours), so the cost is
//! the network's on `1 + flip + yaw_deg.len()` frames. `pi3det detect --no-tta` turns it off;
//! the live `pi3det run` never uses it.

use std::collections::BTreeMap;

use pi3det_geometry::{weighted_box_fusion, BoxFusionConfig, FusionMember, View};
use serde::{Deserialize, Serialize};

use crate::config::PostConfig;
use crate::error::{NnError, Result};
use crate::post_process::{nms_detections, Detection};

/// Which views and how they are fused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TtaConfig {
    /// Add the frame mirrored left/right (y → −y).
    pub flip: bool,
    /// Add the frame turned about the vertical by each of these angles (degrees).
    pub yaw_deg: Vec<f64>,
    /// A box joins the fused cluster it overlaps most in BEV at this IoU or more.
    pub fusion_iou: f64,
    /// Per class name, a `fusion_iou` of its own (small boxes overlap less for the same offset).
    pub class_fusion_iou: BTreeMap<String, f64>,
}

impl Default for TtaConfig {
    fn default() -> Self {
        Self { flip: true, yaw_deg: vec![7.5, -7.5, 15.0, -15.0], fusion_iou: 0.55, class_fusion_iou: BTreeMap::new() }
    }
}

impl TtaConfig {
    /// The frame as it is, then the mirror, then the turns.
    pub fn views(&self) -> Vec<View> {
        let mut v = vec![View::IDENTITY];
        if self.flip {
            v.push(View { flip_y: true, yaw_rad: 0.0 });
        }
        v.extend(self.yaw_deg.iter().map(|d| View { flip_y: false, yaw_rad: d.to_radians() }));
        v
    }

    /// Finite angles, IoUs in (0, 1], class names the detector has.
    pub fn validate(&self, classes: &[String]) -> Result<()> {
        let bad = |m: String| Err(NnError::config("post.tta", format!("post.tta: {m}")));
        if let Some(d) = self.yaw_deg.iter().find(|d| !d.is_finite() || d.abs() >= 180.0) {
            return bad(format!("yaw_deg {d} is not an angle in (−180, 180)"));
        }
        for (name, iou) in std::iter::once(("fusion_iou", &self.fusion_iou))
            .chain(self.class_fusion_iou.iter().map(|(c, v)| (c.as_str(), v)))
        {
            if !(*iou > 0.0 && *iou <= 1.0) {
                return bad(format!("{name}: fusion IoU {iou} is not in (0, 1]"));
            }
        }
        if let Some(c) = self.class_fusion_iou.keys().find(|c| !classes.contains(c)) {
            return bad(format!("class_fusion_iou names {c:?}, not one of the detector's classes {classes:?}"));
        }
        Ok(())
    }

    fn iou_for(&self, class: &str) -> f64 {
        self.class_fusion_iou.get(class).copied().unwrap_or(self.fusion_iou)
    }

    /// One frame's detections from every view, each view's already back in the frame
    /// ([`out_of_view`]) → fused per class, then the post-processing's NMS (per class or over
    /// all) and `nms_post_max`, best first.
    pub fn merge(&self, per_view: &[Vec<Detection>], classes: &[String], post: &PostConfig) -> Vec<Detection> {
        let mut by_class: BTreeMap<usize, Vec<FusionMember>> = BTreeMap::new();
        for (k, dets) in per_view.iter().enumerate() {
            for d in dets {
                by_class.entry(d.class).or_default().push(FusionMember { box3d: d.box3d, score: d.score, view: k });
            }
        }
        let mut fused = Vec::new();
        for (class, members) in by_class {
            let name = classes.get(class).map_or("", String::as_str);
            let cfg = BoxFusionConfig { iou_threshold: self.iou_for(name) };
            fused.extend(weighted_box_fusion(&members, per_view.len(), &cfg).into_iter().map(|f| Detection {
                box3d: f.box3d,
                score: f.score,
                class,
            }));
        }
        // The post-processing's NMS (per class or not), without its score threshold: a box one
        // view alone found scores a fraction of what that view gave it, and stays ranked.
        let post = PostConfig { score_threshold: f64::NEG_INFINITY, ..post.clone() };
        nms_detections(&fused, &post, classes.len(), post.nms_iou, post.nms_post_max)
    }
}

/// Detections seen through `view`, back in the frame.
pub fn out_of_view(dets: &mut [Detection], view: View) {
    dets.iter_mut().for_each(|d| d.box3d = view.out_of_view(&d.box3d));
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::Box3d;

    #[test]
    fn views_of_one_box_fuse_back_to_it() {
        let cfg = TtaConfig::default();
        let views = cfg.views();
        assert_eq!(views.len(), 6);
        assert_eq!(views[0], View::IDENTITY);
        let classes = vec!["Car".to_string(), "Pedestrian".to_string()];
        let car = Box3d::new(12.0, -4.0, 0.8, 4.6, 1.9, 1.6, 0.4);
        let ped = Box3d::new(5.0, 3.0, 0.9, 0.7, 0.6, 1.7, 0.0);
        // Every view sees the car where it is (in its own coordinates); only two see the pedestrian.
        let per_view: Vec<Vec<Detection>> = views
            .iter()
            .enumerate()
            .map(|(k, v)| {
                let mut d = vec![Detection { box3d: v.into_view(&car), score: 0.8, class: 0 }];
                if k < 2 {
                    d.push(Detection { box3d: v.into_view(&ped), score: 0.6, class: 1 });
                }
                out_of_view(&mut d, *v);
                d
            })
            .collect();
        let out = cfg.merge(&per_view, &classes, &PostConfig::default());
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].class, 0);
        for (p, q) in out[0].box3d.to_array().iter().zip(car.to_array()) {
            assert!((p - q).abs() < 1e-9, "{:?}", out[0].box3d);
        }
        assert!((out[0].score - 0.8).abs() < 1e-12);
        assert!((out[1].score - 0.6 * 2.0 / 6.0).abs() < 1e-12);
        assert!((out[1].box3d.x - ped.x).abs() < 1e-9 && (out[1].box3d.y - ped.y).abs() < 1e-9);
    }

    #[test]
    fn bad_settings_are_named() {
        let classes = vec!["Car".to_string()];
        let e = TtaConfig { yaw_deg: vec![f64::NAN], ..Default::default() }.validate(&classes).unwrap_err();
        assert!(e.to_string().contains("yaw_deg"), "{e}");
        let e = TtaConfig { fusion_iou: 0.0, ..Default::default() }.validate(&classes).unwrap_err();
        assert!(e.to_string().contains("fusion IoU"), "{e}");
        let c = BTreeMap::from([("Cyclist".to_string(), 0.4)]);
        let e = TtaConfig { class_fusion_iou: c, ..Default::default() }.validate(&classes).unwrap_err();
        assert!(e.to_string().contains("Cyclist"), "{e}");
    }
}
