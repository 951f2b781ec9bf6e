//! `evaluate` over `FrameInfo`s: frame matching by id, filters, name mapping, breakdowns, and
//! the text / JSON outputs.

use pi3det_data::{FrameInfo, Object, Platform};
use pi3det_eval::{evaluate, format_report, Detection, Detections, EvalOptions, EvalReport};
use pi3det_geometry::Box3d;

fn car(x: f64, y: f64) -> Box3d {
    Box3d::new(x, y, -1.0, 3.9, 1.6, 1.5, 0.2)
}

fn frame(id: &str, platform: Platform, seq: &str, objects: Vec<Object>) -> FrameInfo {
    let mut f = FrameInfo::new(id, Default::default());
    f.platform = platform;
    f.sequence = Some(seq.into());
    f.objects = objects;
    f
}

fn det(name: &str, b: Box3d, score: f64) -> Detection {
    Detection { name: name.into(), score, lidar: Some(b), camera: None, bbox: None, alpha: None }
}

fn dets(frames: Vec<(&str, Vec<Detection>)>) -> Detections {
    Detections { source: "test".into(), frames: frames.into_iter().map(|(k, v)| (k.to_string(), v)).collect() }
}

fn split() -> (Vec<FrameInfo>, Detections) {
    let gt = vec![
        frame(
            "a",
            Platform::Vehicle,
            "s1",
            vec![Object::new("Vehicle", car(10.0, 0.0)), Object::new("Car", car(20.0, 5.0))],
        ),
        frame("b", Platform::Drone, "s2", vec![Object::new("Car", car(15.0, -3.0))]),
        frame("c", Platform::Drone, "s2", vec![]),
    ];
    let d = dets(vec![
        ("a", vec![det("Vehicle", car(10.0, 0.0), 0.9), det("Car", car(40.0, 0.0), 0.95)]),
        ("b", vec![det("Car", car(15.05, -3.0), 0.8), det("Car", car(15.0, -3.0), 0.1)]),
    ]);
    (gt, d)
}

#[test]
fn breakdowns_equal_separate_evaluations() {
    let (gt, d) = split();
    let r = evaluate(&gt, &d, &EvalOptions::default()).unwrap();
    assert_eq!(r.frames_without_detections, 1);
    let names: Vec<&str> = r.groups.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(names, ["platform=vehicle", "platform=drone", "sequence=s1", "sequence=s2"]);
    let drone: Vec<FrameInfo> = gt.iter().filter(|f| f.platform == Platform::Drone).cloned().collect();
    let alone = evaluate(&drone, &d, &EvalOptions { allow_unknown_frames: true, ..EvalOptions::default() }).unwrap();
    assert_eq!(alone.overall.classes, r.groups[1].classes);
    assert_eq!(alone.unknown_detection_frames, 1);
    // Vehicle → Car: the class found in the ground truth is Car, with 3 boxes.
    assert_eq!(r.overall.classes.len(), 1);
    assert_eq!(r.overall.classes[0].num_gt, [3, 3, 3]);
    let none = EvalOptions { per_platform: false, per_sequence: false, ..EvalOptions::default() };
    assert!(evaluate(&gt, &d, &none).unwrap().groups.is_empty());
}

#[test]
fn score_threshold_and_range_filter() {
    let (gt, d) = split();
    // The 0.95 false positive in frame a sits at x = 40: dropped by the range filter.
    let base = evaluate(&gt, &d, &EvalOptions::default()).unwrap();
    let ranged =
        evaluate(&gt, &d, &EvalOptions { bev_range: Some([0.0, -10.0, 30.0, 10.0]), ..EvalOptions::default() })
            .unwrap();
    let bev = |r: &EvalReport| r.overall.classes[0].sets[0].bev.r11[1];
    assert!(bev(&ranged) > bev(&base), "{} {}", bev(&ranged), bev(&base));
    // A threshold above every detection: nothing found.
    let high = evaluate(&gt, &d, &EvalOptions { score_threshold: Some(0.99), ..EvalOptions::default() }).unwrap();
    assert_eq!(bev(&high), 0.0);
}

#[test]
fn unknown_frames_and_duplicates_are_errors() {
    let (gt, _) = split();
    let d = dets(vec![("zzz", vec![])]);
    let e = evaluate(&gt, &d, &EvalOptions::default()).unwrap_err().to_string();
    assert!(e.contains("zzz") && e.contains("not in the ground truth"), "{e}");
    let mut dup = gt.clone();
    dup.push(gt[0].clone());
    assert!(evaluate(&dup, &Detections::default(), &EvalOptions::default()).unwrap_err().to_string().contains("twice"));
}

#[test]
fn report_text_and_json() {
    let (gt, d) = split();
    let r = evaluate(&gt, &d, &EvalOptions::paper()).unwrap();
    let t = format_report(&r);
    assert!(t.contains("Car AP@0.70, 0.70, 0.70:\nbbox AP:"), "{t}");
    assert!(t.contains("Car AP_R40@0.70, 0.50, 0.50:"), "{t}");
    assert!(t.contains("R40 moderate BEV / 3D  @0.70:"), "{t}");
    assert!(t.contains("[platform=drone] 2 frames"), "{t}");
    let j = serde_json::to_string(&r).unwrap();
    let back: EvalReport = serde_json::from_str(&j).unwrap();
    assert_eq!(back.overall.classes[0].sets[0].d3, r.overall.classes[0].sets[0].d3);
    assert!(j.contains("\"3d\""));
}

#[test]
fn nan_survives_json() {
    let m = pi3det_eval::MetricAp { r11: [f64::NAN, 1.0, 2.0], r40: [0.0; 3] };
    let j = serde_json::to_string(&m).unwrap();
    assert_eq!(j, r#"{"r11":[null,1.0,2.0],"r40":[0.0,0.0,0.0]}"#);
    let back: pi3det_eval::MetricAp = serde_json::from_str(&j).unwrap();
    assert!(back.r11[0].is_nan() && back.r11[1] == 1.0);
}
