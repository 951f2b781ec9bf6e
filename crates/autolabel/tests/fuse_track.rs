//! Fusion and tracking on simulated sequences: three simulated detectors (ground truth with
//! seeded misses, noise, displaced boxes and false positives) over simulator frames; fused
//! labels must find more cars at IoU 0.7 than the best detector, tracked labels more than the
//! fused ones. And the files the commands write, and their bad input.

use pi3det_autolabel::fusion::{fuse, FusionConfig, FusionInput};
use pi3det_autolabel::perturb::noise_profiles;
use pi3det_autolabel::perturb::simulate_detector;
use pi3det_autolabel::quality::quality;
use pi3det_autolabel::read_infos;
use pi3det_autolabel::tracking::{track_dataset, TrackingConfig};
use pi3det_autolabel::LabelSet;
use pi3det_data::{FrameInfo, Platform};
use pi3det_sim::{ExportOptions, PlatformPlan, SimConfig};

fn simulated(dir: &std::path::Path) -> Vec<FrameInfo> {
    let plans = [PlatformPlan { platform: Platform::Vehicle, sequences: 3, frames: 20, val_sequences: 0 }];
    let opts = ExportOptions {
        out: dir.to_path_buf(),
        seed: 11,
        overwrite: false,
        per_platform_folders: false,
        layout: None,
        stratify_layouts: false,
    };
    pi3det_sim::export(&SimConfig::default(), &plans, &opts, &mut |_, _| {}).unwrap();
    read_infos(&dir.join("train")).unwrap()
}

fn car_recall(labels: &LabelSet, infos: &[FrameInfo]) -> (f64, f64) {
    let cfg = FusionConfig::default();
    let class_of = |n: &str| cfg.class_index(n).map(|k| cfg.classes[k].name.clone());
    let q = quality(labels, infos, &["Car"], class_of, &[0.7]);
    (q[0].recall, q[0].precision)
}

#[test]
fn fused_beats_the_best_detector_and_tracked_beats_fused() {
    let dir = tempfile::tempdir().unwrap();
    let infos = simulated(dir.path());
    assert!(infos.iter().all(|i| i.timestamp_s.is_some() && i.sequence.is_some()));
    let mut fusion = FusionConfig::default();
    fusion.classes.iter_mut().for_each(|c| c.min_members = 1);
    let singles: Vec<LabelSet> =
        noise_profiles(3).iter().enumerate().map(|(k, n)| simulate_detector(&infos, n, 100 + k as u64)).collect();
    let inputs: Vec<FusionInput> =
        singles.iter().map(|l| FusionInput { labels: l.clone(), class_weights: vec![1.0; 3] }).collect();
    let (fused, stats) = fuse(&inputs, &fusion).unwrap();
    assert_eq!(stats.frames, infos.len());
    let tracked = track_dataset(&infos, &fused, &TrackingConfig::default(), None).unwrap();
    assert_eq!(tracked.stats.sequences, 3);
    let best = singles.iter().map(|s| car_recall(s, &infos).0).fold(0.0, f64::max);
    let (fused_r, _) = car_recall(&fused, &infos);
    let (tracked_r, tracked_p) = car_recall(&tracked.labels, &infos);
    eprintln!("Car recall@0.7: best detector {best:.3}, fused {fused_r:.3}, tracked {tracked_r:.3} (precision {tracked_p:.3})");
    assert!(fused_r > best, "fused {fused_r} vs best single {best}");
    assert!(tracked_r > fused_r, "tracked {tracked_r} vs fused {fused_r}");
    // Track ids: one per box, and an id never appears twice in a frame.
    for (id, boxes) in &tracked.labels.frames {
        let ids = &tracked.track_ids[id];
        assert_eq!(ids.len(), boxes.len());
        let unique: std::collections::BTreeSet<_> = ids.iter().collect();
        assert_eq!(unique.len(), ids.len());
    }
}

#[test]
fn written_labels_read_back_with_track_ids_and_bad_input_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let infos = simulated(&dir.path().join("data"));
    let det = simulate_detector(&infos, &noise_profiles(1)[0], 5);
    let tracked = track_dataset(&infos, &det, &TrackingConfig::default(), None).unwrap();
    let out = dir.path().join("tracked.jsonl");
    tracked.labels.write_jsonl(&out, Some(&tracked.track_ids), false).unwrap();
    // The evaluator's reader takes the file (track ids are an optional field).
    let back = LabelSet::read(&out).unwrap();
    assert_eq!(back.num_boxes(), tracked.labels.num_boxes());
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(text.contains("\"track_ids\""));
    // Nothing is overwritten without being asked.
    let e = tracked.labels.write_jsonl(&out, None, false).unwrap_err().to_string();
    assert!(e.contains("--overwrite"), "{e}");

    // Labels for a frame the data does not have.
    let mut stray = det.clone();
    stray.source = "stray.jsonl".into();
    stray.frames.insert("9999999".into(), Vec::new());
    let e = track_dataset(&infos, &stray, &TrackingConfig::default(), None).unwrap_err().to_string();
    assert!(e.contains("stray.jsonl") && e.contains("9999999"), "{e}");

    // A sequence without timestamps: an error unless a frame rate is given.
    let mut untimed = infos.clone();
    untimed.iter_mut().for_each(|i| i.timestamp_s = None);
    let e = track_dataset(&untimed, &det, &TrackingConfig::default(), None).unwrap_err().to_string();
    assert!(e.contains("no timestamp") && e.contains("--frame-rate"), "{e}");
    assert!(track_dataset(&untimed, &det, &TrackingConfig::default(), Some(10.0)).is_ok());
    let e = track_dataset(&untimed, &det, &TrackingConfig::default(), Some(0.0)).unwrap_err().to_string();
    assert!(e.contains("positive"), "{e}");

    // A class the fusion config does not know.
    let mut odd = det.clone();
    odd.source = "odd.jsonl".into();
    let first = odd.frames.values_mut().find(|v| !v.is_empty()).unwrap();
    first[0].name = "Tram".into();
    let input = FusionInput { labels: odd, class_weights: vec![1.0; 3] };
    let e = fuse(&[input], &FusionConfig::default()).unwrap_err().to_string();
    assert!(e.contains("odd.jsonl") && e.contains("Tram"), "{e}");
}
