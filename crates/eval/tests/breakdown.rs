//! The error breakdown on hand-made splits whose answers follow by hand, and its agreement with
//! the report on a seeded synthetic split.

#[path = "../examples/common/synthetic.rs"]
mod synthetic;

use std::f64::consts::PI;

use pi3det_data::{FrameInfo, Object};
use pi3det_eval::{breakdown, evaluate, Breakdown, ClassBreakdown, Detection, Detections, EvalOptions};
use pi3det_geometry::Box3d;

fn car(x: f64, y: f64) -> Box3d {
    Box3d::new(x, y, -1.0, 3.9, 1.6, 1.5, 0.2)
}

fn gt_obj(b: Box3d, points: Option<u32>) -> Object {
    let mut o = Object::new("Car", b);
    o.num_points = points;
    o
}

fn frame(id: usize, objects: Vec<Object>) -> FrameInfo {
    let mut f = FrameInfo::new(format!("{id:03}"), Default::default());
    f.objects = objects;
    f
}

fn det(b: Box3d, score: f64) -> Detection {
    Detection { name: "Car".into(), score, lidar: Some(b), camera: None, bbox: None, alpha: None }
}

fn dets(frames: Vec<Vec<Detection>>) -> Detections {
    Detections {
        source: "test".into(),
        frames: frames.into_iter().enumerate().map(|(i, d)| (format!("{i:03}"), d)).collect(),
    }
}

fn opts() -> EvalOptions {
    EvalOptions { classes: vec!["Car".into()], ..EvalOptions::default() }
}

fn car_breakdown(gt: &[FrameInfo], d: &Detections) -> ClassBreakdown {
    let b: Breakdown = breakdown(gt, d, &opts()).unwrap();
    assert_eq!(b.classes.len(), 1);
    b.classes.into_iter().next().unwrap()
}

fn close(a: Option<f64>, b: f64) -> bool {
    a.is_some_and(|a| (a - b).abs() < 1e-9)
}

/// 41 frames (R40 needs 41 found GT for 100): a car at 10 m and one at 30 m; a perfect
/// detection of the near one only.
#[test]
fn distance_bins_near_found_mid_missed_far_empty() {
    let gt: Vec<FrameInfo> =
        (0..41).map(|i| frame(i, vec![gt_obj(car(10.0, 0.0), None), gt_obj(car(0.0, 30.0), None)])).collect();
    let d = dets((0..41).map(|i| vec![det(car(10.0, 0.0), 0.5 + i as f64 / 100.0)]).collect());
    let c = car_breakdown(&gt, &d);
    assert_eq!((c.min_iou_bev, c.min_iou_3d), (0.7, 0.7));
    let [near, mid, far] = [&c.by_distance[0], &c.by_distance[1], &c.by_distance[2]];
    assert_eq!((near.min_m, near.max_m, mid.max_m, far.max_m), (0.0, Some(20.0), Some(40.0), None));
    assert_eq!((near.result.num_gt, near.num_det, mid.result.num_gt, mid.num_det), (41, 41, 41, 0));
    assert!(close(near.result.recall_bev, 1.0) && close(near.result.recall_3d, 1.0), "{near:?}");
    assert!(close(near.result.ap_bev_r40_pct, 100.0) && close(near.result.ap_3d_r40_pct, 100.0), "{near:?}");
    assert!(close(mid.result.recall_bev, 0.0) && close(mid.result.ap_bev_r40_pct, 0.0), "{mid:?}");
    // Empty bin: None, which JSON writes as null.
    assert_eq!(far.result.num_gt, 0);
    assert!(
        far.result.recall_bev.is_none() && far.result.ap_bev_r40_pct.is_none() && far.result.ap_3d_r40_pct.is_none()
    );
    let j = serde_json::to_string(&c).unwrap();
    assert!(j.contains(r#""max_m":null,"num_det":0,"num_gt":0"#), "{j}");
    assert!(j.contains(r#""ap_bev_r40_pct":null"#) && !j.contains("NaN"), "{j}");
    let back: ClassBreakdown = serde_json::from_str(&j).unwrap();
    assert_eq!(back, c);
    // No dataset count: every GT skipped by the points bins.
    assert_eq!(c.gt_without_points, 82);
    assert!(c.by_points.iter().all(|p| p.result.num_gt == 0 && p.result.recall_bev.is_none()));
    // The misses have no detection anywhere near: not misplaced.
    assert_eq!((c.misplaced.missed_bev, c.misplaced.misplaced_bev), (41, 0));
    assert!(close(c.misplaced.share_bev, 0.0));
}

#[test]
fn bins_borders_create_no_false_positives() {
    // Both cars found in every frame: each bin sees only its own GT, the other bin's GT and
    // detections are ignored, so both bins are perfect.
    let gt: Vec<FrameInfo> =
        (0..41).map(|i| frame(i, vec![gt_obj(car(10.0, 0.0), None), gt_obj(car(0.0, 30.0), None)])).collect();
    let d = dets(
        (0..41)
            .map(|i| vec![det(car(10.0, 0.0), 0.5 + i as f64 / 100.0), det(car(0.0, 30.0), 0.3 + i as f64 / 1000.0)])
            .collect(),
    );
    let c = car_breakdown(&gt, &d);
    for b in &c.by_distance[..2] {
        assert!(close(b.result.ap_bev_r40_pct, 100.0) && close(b.result.ap_3d_r40_pct, 100.0), "{b:?}");
    }
    // A car at 19.9 m found by a detection whose centre is at 20.1 m: found in the near bin, and
    // the detection (in the mid bin) matches an ignored GT there, so the mid bin has no FP.
    let gt = vec![frame(0, vec![gt_obj(car(19.9, 0.0), None)])];
    let d = dets(vec![vec![det(car(20.1, 0.0), 0.9)]]);
    let c = car_breakdown(&gt, &d);
    assert_eq!((c.by_distance[0].result.found_bev, c.by_distance[0].num_det), (1, 0));
    assert_eq!((c.by_distance[1].result.num_gt, c.by_distance[1].num_det), (0, 1));
}

#[test]
fn z_shift_is_found_in_bev_misplaced_in_3d() {
    // Shifted 0.5 m up, height 1.5 m: BEV IoU 1, 3D IoU 1/2 < 0.7.
    let g = car(10.0, 2.0);
    let d = Box3d { z: g.z + 0.5, ..g };
    let c = car_breakdown(&[frame(0, vec![gt_obj(g, None)])], &dets(vec![vec![det(d, 0.9)]]));
    assert_eq!((c.all.found_bev, c.all.found_3d), (1, 0));
    let m = c.misplaced;
    assert_eq!((m.missed_bev, m.missed_3d, m.misplaced_3d), (0, 1, 1));
    assert!(m.share_bev.is_none() && close(m.share_3d, 1.0), "{m:?}");
    assert_eq!(c.localisation.num_pairs, 1);
    let e = c.localisation.errors.unwrap();
    assert!((e.z_m.median_abs - 0.5).abs() < 1e-12 && (e.z_m.mean_signed - 0.5).abs() < 1e-12, "{e:?}");
    assert!(e.x_m.median_abs < 1e-12 && e.dz_m.mean_abs < 1e-12 && e.heading_rad.median_abs < 1e-12, "{e:?}");
}

/// 41 frames, each car detected 0.5 m too high and 0.6 m too short (BEV exact): 3D AP is 0, and
/// only the rows that make both z and height exact give it back; a false positive far away stays.
#[test]
fn what_if_rows_give_back_what_each_error_costs() {
    let g = car(10.0, 2.0);
    let d = Box3d { z: g.z + 0.5, dz: g.dz - 0.6, ..g };
    let gt: Vec<FrameInfo> = (0..41).map(|i| frame(i, vec![gt_obj(g, None)])).collect();
    let fp = det(car(-20.0, 5.0), 0.95);
    let d = dets((0..41).map(|i| vec![det(d, 0.5 + i as f64 / 100.0), fp.clone()]).collect());
    let c = car_breakdown(&gt, &d);
    assert!(close(c.all.ap_3d_r40_pct, 0.0), "{:?}", c.all);
    let names: Vec<&str> = c.what_if.iter().map(|w| w.exact.as_str()).collect();
    assert_eq!(names, ["z", "height", "z+height", "xy", "length+width", "heading"]);
    let by = |n: &str| c.what_if.iter().find(|w| w.exact == n).unwrap();
    for w in &c.what_if {
        // BEV is exact already; the false positive outscores every true one.
        assert_eq!(w.ap_bev_r40_pct, c.all.ap_bev_r40_pct, "{w:?}");
    }
    assert!(by("z+height").ap_3d_r40_pct == c.all.ap_bev_r40_pct && c.all.ap_bev_r40_pct.unwrap() > 40.0, "{c:?}");
    for n in ["z", "height", "xy", "length+width", "heading"] {
        assert!(close(by(n).ap_3d_r40_pct, 0.0), "{:?}", by(n));
    }
    let text = pi3det_eval::format_breakdown(&Breakdown {
        difficulty: "moderate".into(),
        loose_iou: 0.1,
        classes: vec![c.clone()],
    });
    assert!(text.contains("what if exact") && text.contains("z+height"), "{text}");
}

#[test]
fn heading_off_by_pi_is_no_error() {
    let g = car(10.0, 2.0);
    let d = Box3d { heading: g.heading + PI, ..g };
    let c = car_breakdown(&[frame(0, vec![gt_obj(g, None)])], &dets(vec![vec![det(d, 0.9)]]));
    assert_eq!((c.all.found_bev, c.all.found_3d), (1, 1));
    let e = c.localisation.errors.unwrap();
    assert!(e.heading_rad.median_abs < 1e-9 && e.heading_rad.mean_abs < 1e-9, "{e:?}");
}

#[test]
fn misplaced_needs_a_free_detection_nearby() {
    // Car A: detection 1.5 m along x (BEV IoU ≈ 0.34): missed, misplaced. Car B: no detection.
    // Car C: found; car D, 2 m ahead of C along its heading, overlaps only C's detection (BEV IoU
    // 1.9/5.9), which C took: D is missed and not misplaced.
    let (h, cc) = (0.2f64, car(10.0, -10.0));
    let (a, b, dd) = (car(10.0, 0.0), car(30.0, 10.0), car(cc.x + 2.0 * h.cos(), cc.y + 2.0 * h.sin()));
    let gt = vec![frame(0, [a, b, cc, dd].map(|x| gt_obj(x, None)).to_vec())];
    let d = dets(vec![vec![det(Box3d { x: a.x + 1.5, ..a }, 0.9), det(cc, 0.8)]]);
    let c = car_breakdown(&gt, &d);
    let m = c.misplaced;
    assert_eq!((m.missed_bev, m.misplaced_bev), (3, 1), "{m:?}");
    assert!(close(m.share_bev, 1.0 / 3.0));
    // Localisation pairs: A with its shifted detection, C with its own.
    assert_eq!(c.localisation.num_pairs, 2);
    let e = c.localisation.errors.unwrap();
    assert!((e.x_m.median_abs - 0.75).abs() < 1e-9 && (e.x_m.mean_signed - 0.75).abs() < 1e-9, "{e:?}");
}

#[test]
fn points_bins_use_stored_counts() {
    // Per frame a sparse (5 points), a medium (50) and a dense (500) car, plus one without a count;
    // the sparse and dense ones are found perfectly.
    let gt: Vec<FrameInfo> = (0..41)
        .map(|i| {
            frame(
                i,
                vec![
                    gt_obj(car(10.0, 0.0), Some(5)),
                    gt_obj(car(10.0, 10.0), Some(50)),
                    gt_obj(car(10.0, -10.0), Some(500)),
                    gt_obj(car(30.0, 0.0), None),
                ],
            )
        })
        .collect();
    let found =
        |i: usize| vec![det(car(10.0, 0.0), 0.5 + i as f64 / 100.0), det(car(10.0, -10.0), 0.2 + i as f64 / 1000.0)];
    let d = dets((0..41).map(found).collect());
    let c = car_breakdown(&gt, &d);
    let [sparse, medium, dense] = [&c.by_points[0].result, &c.by_points[1].result, &c.by_points[2].result];
    assert_eq!((c.by_points[0].max_points, c.by_points[1].min_points, c.by_points[2].max_points), (Some(20), 21, None));
    assert_eq!((sparse.num_gt, medium.num_gt, dense.num_gt, c.gt_without_points), (41, 41, 41, 41));
    assert!(close(sparse.recall_bev, 1.0) && close(medium.recall_bev, 0.0) && close(dense.recall_3d, 1.0));
    // The other bins' GT are ignore regions: their detections are not FP.
    assert!(close(sparse.ap_bev_r40_pct, 100.0) && close(dense.ap_bev_r40_pct, 100.0), "{sparse:?} {dense:?}");
    // A confident detection matching no GT is a false positive in every points bin.
    let mut d = dets((0..41).map(found).collect());
    d.frames.get_mut("000").unwrap().push(det(car(50.0, 20.0), 0.99));
    let c = car_breakdown(&gt, &d);
    let (s, dn) = (c.by_points[0].result.ap_bev_r40_pct.unwrap(), c.by_points[2].result.ap_bev_r40_pct.unwrap());
    assert!(s < 100.0 && dn < 100.0, "{s} {dn}");
    assert!(close(c.by_points[0].result.recall_bev, 1.0));
}

#[test]
fn no_detections_give_zero_and_none_not_nan() {
    let gt = vec![frame(0, vec![gt_obj(car(10.0, 0.0), Some(30))])];
    let c = car_breakdown(&gt, &dets(vec![vec![]]));
    assert!(close(c.all.recall_bev, 0.0) && close(c.all.ap_3d_r40_pct, 0.0));
    assert_eq!(c.localisation.num_pairs, 0);
    assert!(c.localisation.errors.is_none());
    let j = serde_json::to_string(&c).unwrap();
    assert!(j.contains(r#""errors":null"#) && !j.contains("NaN"), "{j}");
    // No ground truth at all: every figure None.
    let c = car_breakdown(&[frame(0, vec![])], &dets(vec![vec![det(car(10.0, 0.0), 0.9)]]));
    assert!(c.all.ap_bev_r40_pct.is_none() && c.all.recall_3d.is_none() && c.misplaced.share_3d.is_none());
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let gt = vec![frame(0, vec![gt_obj(car(10.0, 0.0), None)])];
    let mut d = dets(vec![vec![det(car(10.0, 0.0), 0.9)]]);
    d.frames.insert("zzz".into(), vec![]);
    assert!(breakdown(&gt, &d, &opts()).unwrap_err().to_string().contains("zzz"));
    let d = dets(vec![vec![det(Box3d { z: f64::NAN, ..car(10.0, 0.0) }, 0.9)]]);
    assert!(breakdown(&gt, &d, &opts()).unwrap_err().to_string().contains("non-finite"));
}

#[test]
fn all_range_equals_the_report_on_a_synthetic_split() {
    let mut s = synthetic::split(11, 120, 12, 14);
    // Stored point counts for the points bins, falling with distance.
    for (k, o) in s.gt.iter_mut().flat_map(|f| f.objects.iter_mut()).enumerate() {
        o.num_points = (k % 13 != 0).then(|| (4000.0 / (1.0 + o.box3d.x.hypot(o.box3d.y))) as u32);
    }
    let o = EvalOptions { per_platform: false, per_sequence: false, ..EvalOptions::default() };
    let r = evaluate(&s.gt, &s.dets, &o).unwrap();
    let b = breakdown(&s.gt, &s.dets, &o).unwrap();
    assert_eq!(b.classes.iter().map(|c| c.class.as_str()).collect::<Vec<_>>(), ["Car", "Pedestrian"]);
    for (rc, bc) in r.overall.classes.iter().zip(&b.classes) {
        let strict = &rc.sets[0];
        assert_eq!((bc.min_iou_bev, bc.min_iou_3d), (strict.min_overlaps[1], strict.min_overlaps[2]));
        assert_eq!(bc.all.num_gt, rc.num_gt[1]);
        assert_eq!(bc.all.ap_bev_r40_pct, Some(strict.bev.r40[1]), "{}", rc.class);
        assert_eq!(bc.all.ap_3d_r40_pct, Some(strict.d3.r40[1]), "{}", rc.class);
        assert!(strict.bev.r40[1] > 0.0);
        // Bins partition the counted GT (points bins: those with a count).
        assert_eq!(bc.by_distance.iter().map(|d| d.result.num_gt).sum::<usize>(), bc.all.num_gt);
        assert_eq!(bc.by_points.iter().map(|p| p.result.num_gt).sum::<usize>() + bc.gt_without_points, bc.all.num_gt);
        assert!(bc.gt_without_points > 0);
        // Misses are the counted GT the same matching leaves without a detection.
        assert_eq!(bc.misplaced.missed_bev + bc.all.found_bev, bc.all.num_gt);
        assert_eq!(bc.misplaced.missed_3d + bc.all.found_3d, bc.all.num_gt);
        assert!(bc.localisation.num_pairs > 0);
    }
    let text = pi3det_eval::format_breakdown(&b);
    assert!(
        text.contains("Car at IoU BEV 0.70 / 3D 0.70") && text.contains("20-40 m") && text.contains(">100 pts"),
        "{text}"
    );
}
