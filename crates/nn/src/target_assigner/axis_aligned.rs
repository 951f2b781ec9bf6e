//! IoU-based anchor assignment (SECOND / PointPillars; OpenPCDet `AxisAlignedTargetAssigner` with
//! `match_height = False`): per class, anchors are matched to that class's boxes by the IoU of
//! their nearest axis-aligned BEV rectangles; an anchor is positive when its best IoU reaches the
//! class's matched threshold or when it is a box's best anchor, negative below the unmatched
//! threshold, ignored in between. Only anchors near a box are visited, so the cost is the boxes'
//! footprint, not the map size.

use pi3det_geometry::Box3d;

use crate::box_coder::{limit_period, ResidualCoder};
use crate::target_assigner::anchor_generator::{AnchorClassConfig, Anchors};

/// Direction-classifier settings (OpenPCDet `DIR_OFFSET`, `DIR_LIMIT_OFFSET`, `NUM_DIR_BINS`).
pub const DIR_OFFSET: f64 = std::f64::consts::FRAC_PI_4;
pub const NUM_DIR_BINS: usize = 2;

/// Targets of one frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AnchorTargets {
    /// Per anchor: −1 ignored, 0 background, `k + 1` class `k`.
    pub labels: Vec<i64>,
    /// Positive anchors (ascending), their box codes (`7` each) and direction bins.
    pub pos_index: Vec<i64>,
    pub pos_codes: Vec<f32>,
    pub pos_dir: Vec<i64>,
    /// Anchors (ascending) that overlap a box of their class (BEV IoU > 0) without being its
    /// positives: background explained by a box (a badly placed anchor on it), which
    /// Knowledge-Adaptation keeps as background however the model scores it
    /// ([`crate::losses::target_negatives`]).
    pub near_positive: Vec<i64>,
}

/// Axis-aligned rectangle `[x0, y0, x1, y1]` of the box rotated to the nearest multiple of 90°.
pub fn nearest_bev_rect(b: &Box3d) -> [f64; 4] {
    let r = limit_period(b.heading, 0.5, std::f64::consts::PI).abs();
    let (dx, dy) = if r > std::f64::consts::FRAC_PI_4 { (b.dy, b.dx) } else { (b.dx, b.dy) };
    [b.x - 0.5 * dx, b.y - 0.5 * dy, b.x + 0.5 * dx, b.y + 0.5 * dy]
}

pub fn rect_iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    if inter <= 0.0 {
        return 0.0;
    }
    let ua = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter;
    if ua > 0.0 {
        inter / ua
    } else {
        0.0
    }
}

/// Direction bin of a heading.
pub fn dir_bin(heading: f64) -> i64 {
    let period = 2.0 * std::f64::consts::PI / NUM_DIR_BINS as f64;
    let r = limit_period(heading - DIR_OFFSET, 0.0, 2.0 * std::f64::consts::PI);
    ((r / period).floor() as i64).clamp(0, NUM_DIR_BINS as i64 - 1)
}

/// Calls `f(anchor, iou)` for every anchor of class `cls` whose nearest-BEV rectangle overlaps
/// `b`'s (IoU > 0), visiting only the cells near the box.
fn for_each_overlap(anchors: &Anchors, b: &Box3d, cls: usize, mut f: impl FnMut(usize, f64)) {
    let a = anchors.per_location;
    let rect = nearest_bev_rect(b);
    for slot in 0..a {
        if anchors.slot_class[slot] != cls {
            continue;
        }
        // Anchor extent (all anchors of a slot share it).
        let proto = &anchors.boxes[slot];
        let pr = nearest_bev_rect(&Box3d { x: 0.0, y: 0.0, ..*proto });
        // Cells whose anchor rectangle can overlap the box rectangle.
        let x_lo = ((rect[0] - pr[2] - anchors.origin[0]) / anchors.cell[0] - 0.5).floor().max(0.0) as usize;
        let x_hi = ((rect[2] - pr[0] - anchors.origin[0]) / anchors.cell[0] - 0.5).ceil();
        let y_lo = ((rect[1] - pr[3] - anchors.origin[1]) / anchors.cell[1] - 0.5).floor().max(0.0) as usize;
        let y_hi = ((rect[3] - pr[1] - anchors.origin[1]) / anchors.cell[1] - 0.5).ceil();
        if x_hi < 0.0 || y_hi < 0.0 || !x_hi.is_finite() || !y_hi.is_finite() {
            continue;
        }
        let x_hi = (x_hi as usize).min(anchors.w.saturating_sub(1));
        let y_hi = (y_hi as usize).min(anchors.h.saturating_sub(1));
        for iy in y_lo..=y_hi {
            for ix in x_lo..=x_hi {
                let k = (iy * anchors.w + ix) * a + slot;
                let ab = &anchors.boxes[k];
                let ar = [pr[0] + ab.x, pr[1] + ab.y, pr[2] + ab.x, pr[3] + ab.y];
                let iou = rect_iou(&ar, &rect);
                if iou > 0.0 {
                    f(k, iou);
                }
            }
        }
    }
}

/// Assigns `gt` boxes (with class indices `gt_class`) to `anchors`. `classes[k]` holds the anchor
/// config of class `k` (its thresholds). An anchor of class `k` that is not positive and whose IoU
/// with an `ignored` box of class `k` (`ignored_class`) reaches `k`'s unmatched threshold is
/// ignored (−1), exactly as if that box were a GT box it does not match well enough; ignored
/// boxes never make positives, and anchors of other classes do not see them.
pub fn assign(
    anchors: &Anchors,
    classes: &[AnchorClassConfig],
    gt: &[Box3d],
    gt_class: &[usize],
    ignored: &[Box3d],
    ignored_class: &[usize],
) -> AnchorTargets {
    let n = anchors.len();
    let a = anchors.per_location;
    let mut labels = vec![0i64; n];
    // Best IoU and box per anchor among its class's boxes (only anchors near some box are touched).
    let mut best_iou = vec![0f64; n];
    let mut best_gt = vec![u32::MAX; n];
    let mut touched: Vec<usize> = Vec::new();
    let mut forced: Vec<(usize, usize)> = Vec::new(); // (anchor, gt)
    for (g, (b, &cls)) in gt.iter().zip(gt_class).enumerate() {
        let mut gt_best = 0f64;
        let mut gt_best_anchors: Vec<usize> = Vec::new();
        for_each_overlap(anchors, b, cls, |k, iou| {
            if best_gt[k] == u32::MAX {
                touched.push(k);
            }
            if best_gt[k] == u32::MAX || iou > best_iou[k] {
                best_iou[k] = iou;
                best_gt[k] = g as u32;
            }
            if iou > gt_best + 1e-12 {
                gt_best = iou;
                gt_best_anchors.clear();
                gt_best_anchors.push(k);
            } else if (iou - gt_best).abs() <= 1e-12 {
                gt_best_anchors.push(k);
            }
        });
        forced.extend(gt_best_anchors.into_iter().map(|k| (k, g)));
    }
    // Threshold rules on the touched anchors; untouched ones keep IoU 0 → background.
    let mut assigned = vec![u32::MAX; n];
    for &k in &touched {
        let cfg = &classes[anchors.slot_class[k % a]];
        let iou = best_iou[k];
        if iou >= cfg.matched_threshold {
            assigned[k] = best_gt[k];
        } else if iou >= cfg.unmatched_threshold {
            labels[k] = -1;
        }
    }
    for &(k, g) in &forced {
        assigned[k] = g as u32;
    }
    let mut pos: Vec<usize> =
        touched.iter().chain(forced.iter().map(|(k, _)| k)).copied().filter(|&k| assigned[k] != u32::MAX).collect();
    pos.sort_unstable();
    pos.dedup();
    let mut near: Vec<i64> = touched.iter().filter(|&&k| assigned[k] == u32::MAX).map(|&k| k as i64).collect();
    near.sort_unstable();
    let mut t = AnchorTargets { labels, near_positive: near, ..Default::default() };
    for k in pos {
        let g = assigned[k] as usize;
        t.labels[k] = gt_class[g] as i64 + 1;
        t.pos_index.push(k as i64);
        t.pos_codes.extend_from_slice(&ResidualCoder::encode(&gt[g], &anchors.boxes[k]));
        t.pos_dir.push(dir_bin(gt[g].heading));
    }
    // Ignored boxes last: they only turn background anchors of their class into ignored ones.
    for (b, &cls) in ignored.iter().zip(ignored_class) {
        let Some(cfg) = classes.get(cls) else { continue };
        for_each_overlap(anchors, b, cls, |k, iou| {
            if t.labels[k] == 0 && iou >= cfg.unmatched_threshold {
                t.labels[k] = -1;
            }
        });
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::iou::bev_iou;

    fn classes() -> Vec<AnchorClassConfig> {
        vec![
            AnchorClassConfig {
                class: "Car".into(),
                size: [4.0, 2.0, 1.5].into(),
                bottom_z: -1.0,
                rotations: vec![0.0, std::f64::consts::FRAC_PI_2],
                matched_threshold: 0.6,
                unmatched_threshold: 0.45,
            },
            AnchorClassConfig {
                class: "Pedestrian".into(),
                size: [0.8, 0.6, 1.7].into(),
                bottom_z: -1.0,
                rotations: vec![0.0, std::f64::consts::FRAC_PI_2],
                matched_threshold: 0.5,
                unmatched_threshold: 0.35,
            },
        ]
    }

    fn anchors() -> Anchors {
        let c = classes();
        Anchors::generate(&[(0, c[0].clone()), (1, c[1].clone())], 20, 20, [0.5, 0.5], [0.0, 0.0])
    }

    /// Brute force: the same rules over all anchor–box pairs.
    fn brute(anchors: &Anchors, classes: &[AnchorClassConfig], gt: &[Box3d], gc: &[usize]) -> Vec<i64> {
        let a = anchors.per_location;
        let n = anchors.len();
        let iou = |k: usize, g: usize| {
            if anchors.slot_class[k % a] != gc[g] {
                0.0
            } else {
                rect_iou(&nearest_bev_rect(&anchors.boxes[k]), &nearest_bev_rect(&gt[g]))
            }
        };
        let mut labels = vec![0i64; n];
        for (k, l) in labels.iter_mut().enumerate() {
            let (g, best) =
                (0..gt.len())
                    .map(|g| (g, iou(k, g)))
                    .fold((usize::MAX, 0.0), |acc, x| if x.1 > acc.1 { x } else { acc });
            let cfg = &classes[anchors.slot_class[k % a]];
            if best >= cfg.matched_threshold {
                *l = gc[g] as i64 + 1;
            } else if best >= cfg.unmatched_threshold {
                *l = -1;
            }
        }
        for (g, &c) in gc.iter().enumerate() {
            let best = (0..n).map(|k| iou(k, g)).fold(0.0, f64::max);
            if best > 0.0 {
                for (k, l) in labels.iter_mut().enumerate() {
                    if (iou(k, g) - best).abs() <= 1e-12 {
                        *l = c as i64 + 1;
                    }
                }
            }
        }
        labels
    }

    #[test]
    fn matches_brute_force_and_codes_decode_to_the_box() {
        let cls = classes();
        let an = anchors();
        let gt = vec![
            Box3d::new(4.1, 5.2, -0.2, 4.3, 1.9, 1.5, 0.3),
            Box3d::new(7.0, 7.3, -0.2, 3.9, 2.0, 1.5, 1.5),
            Box3d::new(2.2, 8.1, -0.1, 0.7, 0.6, 1.8, 2.0),
            Box3d::new(9.9, 0.1, -0.1, 0.7, 0.6, 1.8, -0.5), // at the map edge
            Box3d::new(40.0, 40.0, -0.1, 4.0, 2.0, 1.5, 0.0), // off the map
        ];
        let gc = vec![0, 0, 1, 1, 0];
        let t = assign(&an, &cls, &gt, &gc, &[], &[]);
        assert_eq!(t.labels, brute(&an, &cls, &gt, &gc));
        assert!(!t.pos_index.is_empty());
        // Every box on the map got a positive anchor; each code decodes back to its box.
        for (j, &k) in t.pos_index.iter().enumerate() {
            let code: [f32; 7] = t.pos_codes[j * 7..j * 7 + 7].try_into().unwrap();
            let b = ResidualCoder::decode(&code, &an.boxes[k as usize]);
            let g = gt.iter().position(|g| bev_iou(g, &b) > 0.999).expect("decodes to a box");
            assert_eq!(t.labels[k as usize], gc[g] as i64 + 1);
            assert_eq!(t.pos_dir[j], dir_bin(gt[g].heading));
        }
        for g in &gt[..4] {
            assert!(t.pos_index.iter().enumerate().any(|(j, &k)| {
                let code: [f32; 7] = t.pos_codes[j * 7..j * 7 + 7].try_into().unwrap();
                bev_iou(g, &ResidualCoder::decode(&code, &an.boxes[k as usize])) > 0.999
            }));
        }
    }

    /// Ignored boxes turn the background anchors of their own class with IoU ≥ the unmatched
    /// threshold into −1 (brute force), leave positives and other classes alone, and add no
    /// positive.
    #[test]
    fn ignored_boxes_ignore_background_anchors_of_their_class_only() {
        let cls = classes();
        let an = anchors();
        let a = an.per_location;
        let gt = vec![Box3d::new(7.0, 7.3, -0.2, 3.9, 2.0, 1.5, 1.5), Box3d::new(2.2, 8.1, -0.1, 0.7, 0.6, 1.8, 2.0)];
        let gc = vec![0, 1];
        // A car overlapping the real car, a car alone, a pedestrian alone.
        let ign = vec![
            Box3d::new(5.6, 6.0, -0.2, 4.3, 1.9, 1.5, 0.3),
            Box3d::new(3.0, 2.5, -0.2, 4.1, 1.8, 1.5, -0.2),
            Box3d::new(7.75, 1.25, -0.1, 0.7, 0.6, 1.8, 0.0),
        ];
        let ic = vec![0, 0, 1];
        let base = assign(&an, &cls, &gt, &gc, &[], &[]);
        let t = assign(&an, &cls, &gt, &gc, &ign, &ic);
        let mut want = base.labels.clone();
        for (k, l) in want.iter_mut().enumerate() {
            let c = an.slot_class[k % a];
            let hit = ign.iter().zip(&ic).any(|(b, &bc)| {
                bc == c && rect_iou(&nearest_bev_rect(&an.boxes[k]), &nearest_bev_rect(b)) >= cls[c].unmatched_threshold
            });
            if *l == 0 && hit {
                *l = -1;
            }
        }
        assert_eq!(t.labels, want);
        assert_eq!((&t.pos_index, &t.pos_codes, &t.pos_dir), (&base.pos_index, &base.pos_codes, &base.pos_dir));
        let newly: Vec<usize> = (0..an.len()).filter(|&k| t.labels[k] == -1 && base.labels[k] != -1).collect();
        for c in [0, 1] {
            assert!(newly.iter().any(|&k| an.slot_class[k % a] == c), "class {c} got ignored anchors");
        }
        // Only the pedestrian ignored: no car anchor changes.
        let t = assign(&an, &cls, &gt, &gc, &ign[2..], &ic[2..]);
        for k in 0..an.len() {
            if an.slot_class[k % a] == 0 {
                assert_eq!(t.labels[k], base.labels[k], "a pedestrian box ignored car anchor {k}");
            }
        }
        // The same box as a pedestrian and as a car: only its own class's anchors are ignored.
        let as_ped = assign(&an, &cls, &[], &[], &ign[..1], &[1]);
        let as_car = assign(&an, &cls, &[], &[], &ign[..1], &[0]);
        assert!(as_car.labels.iter().enumerate().all(|(k, &l)| l == 0 || an.slot_class[k % a] == 0));
        assert!(as_car.labels.contains(&-1) && as_car.pos_index.is_empty());
        assert!(as_ped.labels.iter().enumerate().all(|(k, &l)| l == 0 || an.slot_class[k % a] == 1));
    }

    #[test]
    fn direction_bins() {
        use std::f64::consts::PI;
        // Bin 0 holds headings in [π/4, 5π/4), bin 1 the rest.
        assert_eq!(dir_bin(0.0), 1);
        assert_eq!(dir_bin(PI), 0);
        assert_eq!(dir_bin(-PI / 2.0), 1);
        assert_eq!(dir_bin(PI / 2.0), 0);
        assert_eq!(dir_bin(PI / 4.0 + 1e-9), 0);
    }
}
