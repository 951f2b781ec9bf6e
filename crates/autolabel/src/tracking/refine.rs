//! What offline tracking adds over per-frame boxes: gaps of a confirmed track filled by
//! interpolation, still objects' boxes fused over a window (MS3D++'s rolling KBF), and each
//! box's score pulled towards its track's mean.

use pi3det_geometry::boxes::wrap_angle;
use pi3det_geometry::Box3d;

use super::config::TrackingConfig;
use super::tracker::{Track, TrackBox};
use crate::fusion::{fuse_cluster, FusionConfig, Member};

pub(super) fn refine(raw: super::tracker::RawTrack, class: &str, cfg: &TrackingConfig) -> Track {
    let observed = raw.boxes;
    let is_static = is_static(&observed, cfg);
    let mut boxes = if is_static { fuse_static(&observed, cfg) } else { observed.clone() };
    boxes = interpolate(&boxes, cfg.max_interpolated_gap);
    let mean = observed.iter().map(|b| b.score).sum::<f64>() / observed.len() as f64;
    let w = cfg.score_smoothing;
    for b in &mut boxes {
        b.score = (1.0 - w) * b.score + w * mean;
    }
    Track { id: raw.id, class: class.to_string(), boxes, is_static }
}

/// MS3D++'s motion state: little travel from first to last centre and little spread.
fn is_static(boxes: &[TrackBox], cfg: &TrackingConfig) -> bool {
    let s = &cfg.static_objects;
    if !s.enabled || boxes.len() < s.min_observations {
        return false;
    }
    let (first, last) = (&boxes[0].box3d, &boxes[boxes.len() - 1].box3d);
    let travel = (first.x - last.x).hypot(first.y - last.y);
    let n = boxes.len() as f64;
    let var = |f: fn(&Box3d) -> f64| {
        let m = boxes.iter().map(|b| f(&b.box3d)).sum::<f64>() / n;
        boxes.iter().map(|b| (f(&b.box3d) - m).powi(2)).sum::<f64>() / n
    };
    travel < s.max_travel_m && (var(|b| b.x) + var(|b| b.y)) / 2.0 < s.max_centre_variance_m2
}

/// Each observation replaced by the kernel-density fusion of the observations around it.
fn fuse_static(boxes: &[TrackBox], cfg: &TrackingConfig) -> Vec<TrackBox> {
    let fusion = FusionConfig::default();
    let hw = cfg.static_objects.half_window;
    (0..boxes.len())
        .map(|k| {
            let window = &boxes[k.saturating_sub(hw)..(k + hw + 1).min(boxes.len())];
            let members: Vec<Member> = window
                .iter()
                .map(|b| Member { box3d: b.box3d, score: b.score, weight: b.score.max(1e-6), source: b.frame })
                .collect();
            let fused = fuse_cluster(&members, &fusion).map_or(boxes[k].box3d, |f| f.box3d);
            TrackBox { box3d: fused, ..boxes[k].clone() }
        })
        .collect()
}

/// Boxes for the frames between two observations at most `max_gap` frames apart: position,
/// size and heading linear in the frame index (heading the short way round, front/back
/// confusions folded), score the neighbours' mean.
pub fn interpolate(boxes: &[TrackBox], max_gap: usize) -> Vec<TrackBox> {
    let mut out: Vec<TrackBox> = Vec::with_capacity(boxes.len());
    for (k, b) in boxes.iter().enumerate() {
        if k > 0 {
            let a = &boxes[k - 1];
            let gap = b.frame - a.frame - 1;
            if gap > 0 && gap <= max_gap {
                let mut dh = wrap_angle(b.box3d.heading - a.box3d.heading);
                if dh.abs() > std::f64::consts::FRAC_PI_2 {
                    dh = wrap_angle(dh + std::f64::consts::PI);
                }
                for f in a.frame + 1..b.frame {
                    let t = (f - a.frame) as f64 / (b.frame - a.frame) as f64;
                    let l = |p: f64, q: f64| p + (q - p) * t;
                    let (p, q) = (&a.box3d, &b.box3d);
                    let box3d = Box3d {
                        x: l(p.x, q.x),
                        y: l(p.y, q.y),
                        z: l(p.z, q.z),
                        dx: l(p.dx, q.dx),
                        dy: l(p.dy, q.dy),
                        dz: l(p.dz, q.dz),
                        heading: wrap_angle(p.heading + dh * t),
                    };
                    out.push(TrackBox { frame: f, box3d, score: (a.score + b.score) / 2.0, observed: false });
                }
            }
        }
        out.push(b.clone());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tb(frame: usize, x: f64, heading: f64) -> TrackBox {
        TrackBox {
            frame,
            box3d: Box3d { x, y: 0.0, z: 0.0, dx: 4.0, dy: 2.0, dz: 1.5, heading },
            score: 0.8,
            observed: true,
        }
    }

    #[test]
    fn interpolation_by_hand() {
        let out = interpolate(&[tb(0, 0.0, 3.0), tb(4, 8.0, -3.0)], 5);
        assert_eq!(out.len(), 5);
        assert!((out[2].box3d.x - 4.0).abs() < 1e-12);
        // 3.0 → −3.0 is 0.283 rad the short way through π.
        let expect = wrap_angle(3.0 + wrap_angle(-3.0 - 3.0) * 0.5);
        assert!((out[2].box3d.heading - expect).abs() < 1e-12);
        assert!(!out[1].observed && out[4].observed);
        assert_eq!(interpolate(&[tb(0, 0.0, 0.0), tb(10, 8.0, 0.0)], 5).len(), 2);
    }
}
