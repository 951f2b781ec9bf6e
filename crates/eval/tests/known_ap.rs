//! Hand-made cases whose AP follows by hand from the reference's rules.

use pi3det_eval::{evaluate_kitti, ClassSpec, GroupResult, KittiFrame, KittiObject, Overlaps};

const FAKE_BBOX: [f64; 4] = [0.0, 0.0, 50.0, 50.0];

fn obj(name: &str, x: f64, z: f64, score: f64) -> KittiObject {
    KittiObject {
        name: name.to_string(),
        truncated: 0.0,
        occluded: 0.0,
        alpha: 0.0,
        bbox: FAKE_BBOX,
        dimensions: [4.0, 1.5, 1.8],
        location: [x, 1.5, z],
        rotation_y: 0.3,
        score,
    }
}

fn frame(objects: Vec<KittiObject>) -> KittiFrame {
    KittiFrame { id: String::new(), objects }
}

fn spec(name: &str) -> ClassSpec {
    ClassSpec { name: name.to_string(), overlaps: pi3det_eval::classes::default_overlaps(name).unwrap() }
}

fn eval(gt: &[KittiFrame], dt: &[KittiFrame], classes: &[&str]) -> GroupResult {
    let specs: Vec<ClassSpec> = classes.iter().map(|c| spec(c)).collect();
    evaluate_kitti("test", gt, dt, &specs, true).unwrap()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

/// Asserts every metric and set of class `c` has these (R11, R40) at every difficulty.
fn assert_all(r: &GroupResult, c: usize, r11: f64, r40: f64) {
    for s in &r.classes[c].sets {
        for m in 0..3 {
            let ap = s.metric(m);
            for d in 0..3 {
                assert!(
                    close(ap.r11[d], r11) && close(ap.r40[d], r40),
                    "metric {m} diff {d}: {ap:?}, want {r11} {r40}"
                );
            }
        }
    }
}

/// `n` Car GTs, one per frame, each with a perfect detection.
fn perfect(n: usize) -> GroupResult {
    let gt: Vec<_> = (0..n).map(|i| frame(vec![obj("Car", i as f64, 20.0, 0.0)])).collect();
    let dt: Vec<_> = (0..n).map(|i| frame(vec![obj("Car", i as f64, 20.0, 0.5 + i as f64 / 100.0)])).collect();
    eval(&gt, &dt, &["Car"])
}

#[test]
fn forty_one_perfect_detections_give_100() {
    assert_all(&perfect(41), 0, 100.0, 100.0);
}

#[test]
fn one_perfect_detection_gives_r40_0_and_r11_100_over_11() {
    assert_all(&perfect(1), 0, 100.0 / 11.0, 0.0);
}

#[test]
fn few_perfect_detections_top_out_at_n_minus_1_over_40() {
    // 10 thresholds: slots 0..9 have precision 1; R11 sees slots 0, 4, 8.
    assert_all(&perfect(10), 0, 300.0 / 11.0, 22.5);
    // Many GTs in one frame behave the same as one per frame.
    let gt = vec![frame((0..10).map(|i| obj("Car", 10.0 * i as f64, 20.0, 0.0)).collect())];
    let dt = vec![frame((0..10).map(|i| obj("Car", 10.0 * i as f64, 20.0, 0.9 - i as f64 / 100.0)).collect())];
    assert_all(&eval(&gt, &dt, &["Car"]), 0, 300.0 / 11.0, 22.5);
}

#[test]
fn all_misses_give_0() {
    let gt = vec![frame(vec![obj("Car", 0.0, 20.0, 0.0)]), frame(vec![obj("Car", 5.0, 20.0, 0.0)])];
    // Far away in BEV; the fake 2D boxes still match, so only bev/3d are 0.
    let dt = vec![frame(vec![obj("Car", 30.0, 20.0, 0.9)]), frame(vec![])];
    let r = eval(&gt, &dt, &["Car"]);
    for s in &r.classes[0].sets {
        assert_eq!(s.bev.r40, [0.0; 3]);
        assert_eq!(s.d3.r11, [0.0; 3]);
    }
    // No detections at all.
    let r = eval(&gt, &[frame(vec![]), frame(vec![])], &["Car"]);
    assert_all(&r, 0, 0.0, 0.0);
}

#[test]
fn small_precision_recall_curve() {
    // 4 GTs; detections by score: 0.9 TP, 0.8 FP, 0.7 TP, 0.6 FP, 0.5 TP; one GT missed.
    // Thresholds 0.9, 0.7, 0.5 → precision 1, 2/3, 3/5.
    let gt = vec![frame((0..4).map(|i| obj("Car", 10.0 * i as f64, 20.0, 0.0)).collect())];
    let mut dets = vec![
        obj("Car", 0.0, 20.0, 0.9),
        obj("Car", 0.0, 60.0, 0.8),
        obj("Car", 10.0, 20.0, 0.7),
        obj("Car", 10.0, 60.0, 0.6),
        obj("Car", 20.0, 20.0, 0.5),
    ];
    // Distinct fake-free 2D boxes so the bbox metric behaves like BEV here.
    for (k, d) in dets.iter_mut().enumerate() {
        d.bbox = [100.0 * k as f64, 0.0, 100.0 * k as f64 + 50.0, 50.0];
    }
    let mut gt = gt;
    for (k, g) in gt[0].objects.iter_mut().enumerate() {
        g.bbox = [100.0 * [0, 2, 4, 9][k] as f64, 0.0, 100.0 * [0, 2, 4, 9][k] as f64 + 50.0, 50.0];
    }
    let r = eval(&gt, &[frame(dets)], &["Car"]);
    assert_all(&r, 0, 100.0 / 11.0, (2.0 / 3.0 + 0.6) / 40.0 * 100.0);
}

#[test]
fn zero_ground_truth_gives_0_without_dividing_by_zero() {
    let gt = vec![frame(vec![obj("Car", 0.0, 20.0, 0.0)])];
    let dt = vec![frame(vec![obj("Pedestrian", 0.0, 40.0, 0.9)])];
    let r = eval(&gt, &dt, &["Car", "Pedestrian"]);
    assert_all(&r, 1, 0.0, 0.0);
    assert_eq!(r.classes[1].num_gt, [0, 0, 0]);
    let r = eval(&[frame(vec![])], &[frame(vec![])], &["Car"]);
    assert_all(&r, 0, 0.0, 0.0);
    let r = eval(&[], &[], &["Car"]);
    assert_all(&r, 0, 0.0, 0.0);
}

#[test]
fn wrong_class_detections_are_neither_tp_nor_fp() {
    let gt = vec![frame(vec![obj("Car", 0.0, 20.0, 0.0), obj("Car", 10.0, 20.0, 0.0)])];
    let clean = vec![frame(vec![obj("Car", 0.0, 20.0, 0.8), obj("Car", 10.0, 20.0, 0.7)])];
    let mut noisy = clean.clone();
    // A perfectly placed Pedestrian on the first car with a higher score, and one elsewhere.
    noisy[0].objects.insert(0, obj("Pedestrian", 0.0, 20.0, 0.95));
    noisy[0].objects.push(obj("Pedestrian", 40.0, 20.0, 0.99));
    let a = eval(&gt, &clean, &["Car"]);
    let b = eval(&gt, &noisy, &["Car"]);
    assert_all(&a, 0, 100.0 / 11.0, 2.5);
    assert_eq!(a.classes[0].sets, b.classes[0].sets);
}

#[test]
fn neighbour_class_ground_truth_is_ignored_and_consumes() {
    // A Van found by a Car detection: no TP, no FP; the real car is found.
    let gt = vec![frame(vec![obj("Van", 0.0, 20.0, 0.0), obj("Car", 10.0, 20.0, 0.0)])];
    let dt = vec![frame(vec![obj("Car", 0.0, 20.0, 0.9), obj("Car", 10.0, 20.0, 0.8)])];
    let mut r = eval(&gt, &dt, &["Car"]);
    assert_eq!(r.classes[0].num_gt, [1, 1, 1]);
    // The fake 2D boxes all coincide; look at BEV and 3D only.
    for s in r.classes.remove(0).sets {
        assert!(close(s.bev.r11[1], 100.0 / 11.0) && close(s.d3.r11[1], 100.0 / 11.0), "{s:?}");
    }
}

#[test]
fn overlap_must_be_strictly_greater() {
    // Shift by a third of the length along the box axis: IoU exactly 0.5 in BEV and 3D.
    let mut g = obj("Pedestrian", 0.0, 20.0, 0.0);
    g.rotation_y = 0.0;
    g.dimensions = [3.0, 1.5, 1.0];
    let mut d = g.clone();
    d.location[0] = 1.0;
    d.score = 0.9;
    let r = eval(&[frame(vec![g])], &[frame(vec![d])], &["Pedestrian"]);
    let [strict, loose] = [&r.classes[0].sets[0], &r.classes[0].sets[1]];
    assert_eq!(strict.bev.r11, [0.0; 3]);
    assert_eq!(strict.d3.r11, [0.0; 3]);
    assert!(close(loose.bev.r11[0], 100.0 / 11.0) && close(loose.d3.r11[0], 100.0 / 11.0));
}

#[test]
fn identical_rotated_boxes_have_iou_1() {
    // The reference's float32 kernel returns 0 or 1/3 for many such pairs (mmdet3d #972).
    for ry in [0.0, 0.1, std::f64::consts::FRAC_PI_4, std::f64::consts::FRAC_PI_2, 2.9, -1.2] {
        let mut g = obj("Car", 13.7, 41.2, 0.0);
        g.rotation_y = ry;
        let mut d = g.clone();
        d.score = 0.5;
        let r = eval(&[frame(vec![g])], &[frame(vec![d])], &["Car"]);
        assert_all(&r, 0, 100.0 / 11.0, 0.0);
    }
}

#[test]
fn touching_boxes_do_not_match() {
    let g = obj("Car", 0.0, 20.0, 0.0);
    let mut d = g.clone();
    // Next to it along its length: BEV edges touch.
    d.location = [4.0 * 0.3f64.cos(), 1.5, 20.0 - 4.0 * 0.3f64.sin()];
    d.score = 0.9;
    let r = eval(&[frame(vec![g.clone()])], &[frame(vec![d])], &["Car"]);
    assert_eq!(r.classes[0].sets[1].bev.r11, [0.0; 3]);
    // On top of it: BEV IoU 1, heights only touch.
    let mut d = g.clone();
    d.location[1] -= 1.5;
    d.score = 0.9;
    let r = eval(&[frame(vec![g])], &[frame(vec![d])], &["Car"]);
    assert!(close(r.classes[0].sets[0].bev.r11[0], 100.0 / 11.0));
    assert_eq!(r.classes[0].sets[1].d3.r11, [0.0; 3]);
}

#[test]
fn small_detections_are_ignored_per_difficulty() {
    // KITTI fields: a 60 px high car found by a detection only 30 px high in the image.
    let mut g = obj("Car", 0.0, 20.0, 0.0);
    g.bbox = [100.0, 100.0, 200.0, 160.0];
    let mut d = g.clone();
    d.bbox = [100.0, 100.0, 200.0, 130.0];
    d.score = 0.9;
    let r = eval(&[frame(vec![g])], &[frame(vec![d])], &["Car"]);
    let bev = r.classes[0].sets[0].bev;
    // Easy (min 40 px): the ignored detection consumes the GT: no TP, no FN → no threshold → 0.
    // Moderate and hard (25 px): a true positive.
    assert_eq!(bev.r11[0], 0.0);
    assert!(close(bev.r11[1], 100.0 / 11.0) && close(bev.r11[2], 100.0 / 11.0));
}

#[test]
fn dontcare_removes_false_positives_for_bbox_only() {
    let mut g = obj("Car", 0.0, 20.0, 0.0);
    g.bbox = [0.0, 0.0, 100.0, 60.0];
    let mut dc = obj("DontCare", -10.0, 20.0, 0.0);
    dc.bbox = [500.0, 0.0, 700.0, 100.0];
    let mut tp = g.clone();
    tp.score = 0.5;
    // A confident detection far away in 3D, inside the DontCare region in the image.
    let mut fp = obj("Car", 30.0, 50.0, 0.9);
    fp.bbox = [520.0, 10.0, 600.0, 80.0];
    let r = eval(&[frame(vec![g, dc])], &[frame(vec![fp, tp])], &["Car"]);
    let s = &r.classes[0].sets[0];
    // bbox: the FP is forgiven → precision 1 at the only threshold.
    assert!(close(s.bbox.r11[0], 100.0 / 11.0), "{s:?}");
    // bev: precision 1/2.
    assert!(close(s.bev.r11[0], 50.0 / 11.0), "{s:?}");
}

#[test]
fn aos_follows_heading_error() {
    let g = obj("Car", 0.0, 20.0, 0.0);
    let mut d = g.clone();
    d.score = 0.9;
    d.alpha = std::f64::consts::FRAC_PI_2;
    let r = eval(&[frame(vec![g])], &[frame(vec![d])], &["Car"]);
    let aos = r.classes[0].sets[0].aos.unwrap();
    // Similarity (1 + cos 90°)/2 = 0.5 at slot 0.
    assert!(close(aos.r11[0], 50.0 / 11.0), "{aos:?}");
}

#[test]
fn custom_overlaps_for_other_classes() {
    let g = obj("Sign", 0.0, 20.0, 0.0);
    let mut d = g.clone();
    d.score = 0.9;
    let c = ClassSpec { name: "Sign".into(), overlaps: Overlaps { strict: [0.9; 3], loose: [0.1; 3] } };
    let r = evaluate_kitti("x", &[frame(vec![g])], &[frame(vec![d])], &[c], false).unwrap();
    assert!(close(r.classes[0].sets[0].d3.r11[0], 100.0 / 11.0));
    assert!(r.classes[0].sets[0].aos.is_none());
}
