//! MS3D++'s kernel-density box fusion of several detectors' boxes (`pi3det fuse`): per frame and
//! class, detections above the score thresholds are clustered by a ball query on their centres
//! ([`cluster`]), each cluster becomes one box ([`kbf`]), and rotated BEV NMS removes fused
//! boxes of overlapping clusters.

pub mod cluster;
pub mod config;
pub mod kbf;

use std::collections::BTreeMap;

use pi3det_data::Object;
use pi3det_geometry::{nms, NmsConfig};
use rayon::prelude::*;
use serde::Serialize;

pub use config::{Bandwidths, ClassFusion, FusionConfig};
pub use kbf::{fuse_cluster, Fused, Member};

use crate::labels::LabelSet;
use crate::AutolabelError;

/// One detector's boxes and its weight per class of the config (MS3D++'s per-detector class
/// weights; 0 leaves the detector out for that class).
#[derive(Debug, Clone)]
pub struct FusionInput {
    pub labels: LabelSet,
    pub class_weights: Vec<f64>,
}

/// What fusion did, summed over frames.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FusionStats {
    pub frames: usize,
    pub detections: usize,
    /// Detections above the global and the class score threshold, with weight > 0.
    pub candidates: usize,
    pub clusters: usize,
    pub fused: usize,
}

/// Fuses the inputs frame by frame (every frame id of any input). A detection of a class the
/// config does not know is an error naming the input and the frame.
pub fn fuse(inputs: &[FusionInput], cfg: &FusionConfig) -> Result<(LabelSet, FusionStats), AutolabelError> {
    cfg.validate()?;
    for input in inputs {
        if input.class_weights.len() != cfg.classes.len() {
            return Err(AutolabelError::Config(format!(
                "{}: {} class weights for {} classes",
                input.labels.source.display(),
                input.class_weights.len(),
                cfg.classes.len()
            )));
        }
        for (frame, objects) in &input.labels.frames {
            if let Some(o) = objects.iter().find(|o| cfg.class_index(&o.name).is_none()) {
                return Err(AutolabelError::invalid(
                    &input.labels.source,
                    format!(
                        "frame {frame}: class {:?} is not one the fusion config knows ({:?})",
                        o.name,
                        cfg.known_names()
                    ),
                ));
            }
        }
    }
    let ids: std::collections::BTreeSet<&String> = inputs.iter().flat_map(|i| i.labels.frames.keys()).collect();
    let per_frame: Vec<(String, Vec<Object>, FusionStats)> = ids
        .into_par_iter()
        .map(|id| {
            let frame: Vec<(&[Object], &[f64])> = inputs
                .iter()
                .map(|i| (i.labels.frames.get(id).map_or(&[][..], Vec::as_slice), i.class_weights.as_slice()))
                .collect();
            let (objects, stats) = fuse_frame(&frame, cfg);
            (id.clone(), objects, stats)
        })
        .collect();
    let mut out = LabelSet::default();
    let mut total = FusionStats::default();
    for (id, objects, s) in per_frame {
        total.frames += 1;
        total.detections += s.detections;
        total.candidates += s.candidates;
        total.clusters += s.clusters;
        total.fused += objects.len();
        out.frames.insert(id, objects);
    }
    Ok((out, total))
}

/// Fuses one frame: each input's detections with its class weights. Classes the config does
/// not know are skipped here ([`fuse`] rejects them up front).
pub fn fuse_frame(inputs: &[(&[Object], &[f64])], cfg: &FusionConfig) -> (Vec<Object>, FusionStats) {
    let mut stats = FusionStats { detections: inputs.iter().map(|(o, _)| o.len()).sum(), ..Default::default() };
    let mut by_class: BTreeMap<usize, Vec<Member>> = BTreeMap::new();
    for (source, (objects, weights)) in inputs.iter().enumerate() {
        for o in objects.iter() {
            let Some(k) = cfg.class_index(&o.name) else { continue };
            let score = o.score.unwrap_or(1.0);
            let weight = score * weights[k];
            if score > cfg.min_score && score > cfg.classes[k].score_threshold && weight > 0.0 {
                by_class.entry(k).or_default().push(Member { box3d: o.box3d, score, weight, source });
            }
        }
    }
    let mut out = Vec::new();
    for (k, members) in by_class {
        let class = &cfg.classes[k];
        stats.candidates += members.len();
        let centres: Vec<[f64; 3]> = members.iter().map(|m| [m.box3d.x, m.box3d.y, m.box3d.z]).collect();
        let clusters = cluster::ball_clusters(&centres, class.radius_m, class.min_members);
        stats.clusters += clusters.len();
        let fused: Vec<Fused> = clusters
            .iter()
            .filter_map(|c| fuse_cluster(&c.iter().map(|&i| members[i].clone()).collect::<Vec<_>>(), cfg))
            .collect();
        let boxes: Vec<_> = fused.iter().map(|f| f.box3d).collect();
        let scores: Vec<f64> = fused.iter().map(|f| f.score).collect();
        let nms_cfg = NmsConfig {
            iou_threshold: class.nms_iou,
            score_threshold: f64::NEG_INFINITY,
            pre_max_size: usize::MAX,
            post_max_size: usize::MAX,
        };
        for i in nms(&boxes, &scores, &nms_cfg) {
            let mut o = Object::new(class.name.clone(), fused[i].box3d);
            o.score = Some(fused[i].score);
            out.push(o);
        }
    }
    stats.fused = out.len();
    (out, stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::Box3d;

    fn det(name: &str, x: f64, score: f64) -> Object {
        let mut o = Object::new(name, Box3d { x, y: 0.0, z: 0.0, dx: 4.0, dy: 1.8, dz: 1.6, heading: 0.0 });
        o.score = Some(score);
        o
    }

    #[test]
    fn four_detectors_agreeing_make_one_box_and_three_do_not() {
        let cfg = FusionConfig::default();
        let a = [det("Car", 10.0, 0.9), det("Pedestrian", 30.0, 0.9)];
        let b = [det("Car", 10.2, 0.8)];
        let c = [det("Vehicle", 9.9, 0.7)];
        let d = [det("car", 10.1, 0.6), det("Car", 50.0, 0.15)];
        let w = [1.0, 1.0, 1.0];
        let (out, stats) = fuse_frame(&[(&a, &w), (&b, &w), (&c, &w), (&d, &w)], &cfg);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].name, "Car");
        // The 0.15 car is below the car threshold 0.2.
        assert_eq!(stats.candidates, 5);
        let (out, _) = fuse_frame(&[(&a, &w), (&b, &w), (&c, &w)], &cfg);
        assert!(out.is_empty());
        // A weight of 0 for cars leaves a detector out of the car clusters.
        let w0 = [0.0, 1.0, 1.0];
        let (out, _) = fuse_frame(&[(&a, &w), (&b, &w), (&c, &w), (&d, &w0)], &cfg);
        assert!(out.is_empty());
    }
}
