//! Offline multi-object tracking of one sequence: per class, predict every track with its
//! Kalman filter, associate by BEV GIoU with Hungarian matching, update, birth and death — then,
//! with the whole sequence seen, keep the tracks that were confirmed, fill their gaps and refine
//! them ([`super::refine`]). Works in the world frame, so a moving sensor does not move still
//! objects.

use pathfinding::prelude::{kuhn_munkres, Matrix};
use pi3det_data::Object;
use pi3det_geometry::{Box3d, Pose};

use super::config::{TrackClass, TrackingConfig};
use super::giou::bev_giou;
use super::kalman::BoxFilter;
use super::refine;

/// One frame of a sequence, in time order.
#[derive(Debug, Clone)]
pub struct TrackFrame {
    pub frame_id: String,
    pub timestamp_s: f64,
    pub world_from_lidar: Pose,
    /// Detections in the LiDAR frame.
    pub detections: Vec<Object>,
}

/// A box of a track at one frame, in the world frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackBox {
    pub frame: usize,
    pub box3d: Box3d,
    pub score: f64,
    /// `false` for boxes filled in between observations.
    pub observed: bool,
}

/// A finished track.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    pub id: u64,
    pub class: String,
    pub boxes: Vec<TrackBox>,
    pub is_static: bool,
}

struct Active {
    id: u64,
    filter: BoxFilter,
    misses: usize,
    boxes: Vec<TrackBox>,
}

/// Tracks every configured class of `frames`; ids start at `*next_id` and advance it.
pub fn track_sequence(frames: &[TrackFrame], cfg: &TrackingConfig, next_id: &mut u64) -> Vec<Track> {
    let mut out = Vec::new();
    for class in &cfg.classes {
        for boxes in track_class(frames, class, next_id) {
            let observations = boxes.boxes.iter().filter(|b| b.observed).count();
            let confident = boxes.boxes.iter().filter(|b| b.observed && b.score >= class.confident_score).count();
            if observations < class.min_hits || confident < class.min_confident_hits {
                continue;
            }
            out.push(refine::refine(boxes, &class.name, cfg));
        }
    }
    out
}

pub(super) struct RawTrack {
    pub(super) id: u64,
    pub(super) boxes: Vec<TrackBox>,
}

fn track_class(frames: &[TrackFrame], class: &TrackClass, next_id: &mut u64) -> Vec<RawTrack> {
    let mut active: Vec<Active> = Vec::new();
    let mut done = Vec::new();
    for (fi, frame) in frames.iter().enumerate() {
        let dt_s = if fi == 0 { 0.0 } else { (frame.timestamp_s - frames[fi - 1].timestamp_s).max(0.0) };
        let dets: Vec<(Box3d, f64)> = frame
            .detections
            .iter()
            .filter(|o| o.name == class.name && o.score.unwrap_or(1.0) >= class.min_score)
            .map(|o| (o.box3d.transformed(&frame.world_from_lidar), o.score.unwrap_or(1.0)))
            .collect();
        for t in &mut active {
            t.filter.predict(dt_s);
        }
        let predicted: Vec<Box3d> = active.iter().map(|t| t.filter.state_box()).collect();
        let pairs = associate(&predicted, &dets.iter().map(|d| d.0).collect::<Vec<_>>(), class.min_giou);
        let mut det_used = vec![false; dets.len()];
        let mut track_hit = vec![false; active.len()];
        for (ti, di) in pairs {
            let t = &mut active[ti];
            t.filter.update(&dets[di].0);
            t.misses = 0;
            t.boxes.push(TrackBox { frame: fi, box3d: t.filter.state_box(), score: dets[di].1, observed: true });
            det_used[di] = true;
            track_hit[ti] = true;
        }
        let mut still = Vec::with_capacity(active.len());
        for (t, hit) in active.into_iter().zip(track_hit) {
            let misses = if hit { 0 } else { t.misses + 1 };
            if misses > class.max_misses {
                done.push(RawTrack { id: t.id, boxes: t.boxes });
            } else {
                still.push(Active { misses, ..t });
            }
        }
        active = still;
        for (di, (b, score)) in dets.iter().enumerate() {
            if !det_used[di] {
                *next_id += 1;
                let boxes = vec![TrackBox { frame: fi, box3d: *b, score: *score, observed: true }];
                active.push(Active { id: *next_id, filter: BoxFilter::new(b), misses: 0, boxes });
            }
        }
    }
    done.extend(active.into_iter().map(|t| RawTrack { id: t.id, boxes: t.boxes }));
    done.sort_by_key(|r| r.id);
    done
}

/// Track/detection pairs maximising the summed GIoU margin over `min_giou` (Hungarian), only
/// pairs above it.
fn associate(tracks: &[Box3d], dets: &[Box3d], min_giou: f64) -> Vec<(usize, usize)> {
    if tracks.is_empty() || dets.is_empty() {
        return Vec::new();
    }
    let n = tracks.len().max(dets.len());
    let mut giou = vec![vec![f64::NEG_INFINITY; dets.len()]; tracks.len()];
    let mut w = Matrix::new(n, n, 0i64);
    for (i, t) in tracks.iter().enumerate() {
        for (j, d) in dets.iter().enumerate() {
            // Boxes farther apart than both their sizes cannot pass any GIoU gate worth using.
            if (t.x - d.x).hypot(t.y - d.y) > 4.0 * (t.bev_radius() + d.bev_radius()) {
                continue;
            }
            let g = bev_giou(t, d);
            giou[i][j] = g;
            if g > min_giou {
                w[(i, j)] = ((g - min_giou) * 1e6).round() as i64 + 1;
            }
        }
    }
    let (_, assignment) = kuhn_munkres(&w);
    assignment
        .into_iter()
        .enumerate()
        .filter(|&(i, j)| i < tracks.len() && j < dets.len() && giou[i][j] > min_giou)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn car(x: f64, y: f64, score: f64) -> Object {
        let mut o = Object::new("Car", Box3d { x, y, z: 0.0, dx: 4.0, dy: 1.8, dz: 1.5, heading: 0.0 });
        o.score = Some(score);
        o
    }

    fn frames(dets: Vec<Vec<Object>>) -> Vec<TrackFrame> {
        dets.into_iter()
            .enumerate()
            .map(|(i, d)| TrackFrame {
                frame_id: format!("{i:06}"),
                timestamp_s: 0.1 * i as f64,
                world_from_lidar: Pose::identity(),
                detections: d,
            })
            .collect()
    }

    #[test]
    fn hungarian_prefers_the_better_total() {
        let t = [Box3d { x: 0.0, y: 0.0, z: 0.0, dx: 4.0, dy: 2.0, dz: 1.5, heading: 0.0 }, Box3d { x: 3.0, ..t0() }];
        let d = [Box3d { x: 2.0, ..t0() }, Box3d { x: 4.0, ..t0() }];
        // Greedy would give track 1 → det 0 (or track 0 → det 0 then 1 → 1); both-matched wins.
        let mut p = associate(&t, &d, -0.3);
        p.sort();
        assert_eq!(p, vec![(0, 0), (1, 1)]);
        assert!(associate(&t, &[Box3d { x: 40.0, ..t0() }], -0.3).is_empty());
    }

    fn t0() -> Box3d {
        Box3d { x: 0.0, y: 0.0, z: 0.0, dx: 4.0, dy: 2.0, dz: 1.5, heading: 0.0 }
    }

    #[test]
    fn two_crossing_cars_keep_their_ids_through_a_missed_frame() {
        // Car A moves +x at 10 m/s on y = 0, car B −x on y = 4; frame 3 misses car A.
        let dets: Vec<Vec<Object>> = (0..8)
            .map(|i| {
                let t = 0.1 * i as f64;
                let mut v = vec![car(-10.0 + 10.0 * t, 4.0, 0.8)];
                if i != 3 {
                    v.push(car(10.0 * t, 0.0, 0.9));
                }
                v
            })
            .collect();
        let mut cfg = TrackingConfig::default();
        cfg.static_objects.enabled = false;
        let mut next = 0;
        let tracks = track_sequence(&frames(dets), &cfg, &mut next);
        assert_eq!(tracks.len(), 2, "{tracks:?}");
        let a = tracks.iter().find(|t| t.boxes[0].box3d.y.abs() < 1.0).unwrap();
        assert_eq!(a.boxes.len(), 8);
        let filled = a.boxes.iter().find(|b| b.frame == 3).unwrap();
        assert!(!filled.observed);
        assert!((filled.box3d.x - 3.0).abs() < 0.3, "{filled:?}");
        assert!(tracks.iter().all(|t| t.boxes.windows(2).all(|w| w[0].frame + 1 == w[1].frame)));
    }

    #[test]
    fn a_single_false_positive_is_not_born() {
        let mut dets: Vec<Vec<Object>> = (0..8).map(|_| vec![car(5.0, 5.0, 0.9)]).collect();
        dets[2].push(car(30.0, -8.0, 0.95));
        let mut next = 0;
        let tracks = track_sequence(&frames(dets), &TrackingConfig::default(), &mut next);
        assert_eq!(tracks.len(), 1);
        assert!(tracks[0].is_static);
    }
}
