//! The real frames in `../shared/data`: ground truth scored against itself gives exactly what the
//! reference's rules give for that many boxes (R40 = (n−1)/40, R11 = ⌈n/4⌉/11 for n ≤ 40 valid
//! boxes, 0 for none), on KITTI (real difficulty fields) and on the same frames in the Pi3DET
//! layout (fake KITTI fields: easy = moderate = hard).

use std::path::{Path, PathBuf};

use pi3det_data::FrameInfo;
use pi3det_eval::difficulty::{MAX_OCCLUSION, MAX_TRUNCATION, MIN_HEIGHT};
use pi3det_eval::{breakdown_dataset, evaluate_dataset, Breakdown, Detections, EvalOptions, EvalReport};

fn shared() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("notice: {} not found; skipping the shared-data tests", p.display());
        None
    }
}

/// The AP the reference gives to `n` valid ground truths all found with precision 1.
fn perfect(n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 0.0);
    }
    let slots = n.min(41);
    let r11 = (0..41).step_by(4).filter(|&i| i < slots).count() as f64 / 11.0 * 100.0;
    let r40 = (slots - 1) as f64 / 40.0 * 100.0;
    (r11, r40)
}

fn check(r: &EvalReport, valid: impl Fn(&str, usize) -> usize) {
    for c in &r.overall.classes {
        for d in 0..3 {
            let n = valid(&c.class, d);
            assert_eq!(c.num_gt[d], n, "{} difficulty {d}", c.class);
            let (r11, r40) = perfect(n);
            for s in &c.sets {
                let metrics = [("bbox", &s.bbox), ("bev", &s.bev), ("3d", &s.d3)];
                for (m, ap) in metrics.into_iter().chain(s.aos.as_ref().map(|a| ("aos", a))) {
                    assert!(
                        (ap.r11[d] - r11).abs() < 1e-9,
                        "{} {m} difficulty {d}: R11 {} want {r11}",
                        c.class,
                        ap.r11[d]
                    );
                    assert!(
                        (ap.r40[d] - r40).abs() < 1e-9,
                        "{} {m} difficulty {d}: R40 {} want {r40}",
                        c.class,
                        ap.r40[d]
                    );
                }
            }
        }
    }
}

fn opts() -> EvalOptions {
    EvalOptions { classes: vec!["Car".into(), "Pedestrian".into(), "Cyclist".into()], ..EvalOptions::default() }
}

/// The KITTI labels as a KITTI result folder (score column added, DontCare left out), and all
/// label lines.
fn kitti_labels_as_results(root: &Path) -> (tempfile::TempDir, Detections, Vec<String>) {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut labels = Vec::new();
    for entry in std::fs::read_dir(root.join("label_2")).expect("label_2") {
        let p = entry.expect("entry").path();
        let text = std::fs::read_to_string(&p).expect("label");
        let lines: String = text
            .lines()
            .filter(|l| !l.starts_with("DontCare") && !l.trim().is_empty())
            .enumerate()
            .map(|(k, l)| format!("{l} {}\n", 0.9 - k as f64 * 0.01))
            .collect();
        std::fs::write(dir.path().join(p.file_name().expect("name")), lines).expect("write");
        labels.extend(text.lines().map(str::to_string).collect::<Vec<_>>());
    }
    let dets = Detections::read(dir.path()).expect("read results");
    (dir, dets, labels)
}

#[test]
fn kitti_ground_truth_against_itself() {
    let Some(data) = shared() else { return };
    let root = data.join("kitti/training");
    let ds = pi3det_data::open(&root).expect("open KITTI");
    let (_dir, dets, labels) = kitti_labels_as_results(&root);
    let r = evaluate_dataset(ds.as_ref(), &dets, &opts()).expect("evaluate");
    assert_eq!(r.kitti_frames, 6);
    // Valid boxes by the difficulty rules, counted straight from the label lines.
    let valid = |class: &str, d: usize| {
        labels
            .iter()
            .filter(|l| {
                let f: Vec<&str> = l.split_whitespace().collect();
                let num = |i: usize| f[i].parse::<f64>().expect("number");
                f[0].eq_ignore_ascii_case(class)
                    && num(2) <= MAX_OCCLUSION[d]
                    && num(1) <= MAX_TRUNCATION[d]
                    && num(7) - num(5) > MIN_HEIGHT[d]
            })
            .count()
    };
    assert_eq!((valid("Car", 0), valid("Car", 1), valid("Pedestrian", 2), valid("Cyclist", 2)), (1, 3, 2, 0));
    check(&r, valid);
}

#[test]
fn pi3det_sample_ground_truth_against_itself() {
    let Some(data) = shared() else { return };
    let ds = pi3det_data::open(&data.join("pi3det_sample")).expect("open Pi3DET sample");
    let infos: Vec<FrameInfo> = (0..ds.len()).map(|i| ds.info(i).expect("info")).collect();
    let dets = Detections::from_objects(infos.iter().map(|f| {
        let objects = f.objects.iter().enumerate().map(|(k, o)| {
            let mut o = o.clone();
            o.score = Some(0.9 - k as f64 * 0.01);
            o
        });
        (f.id.clone(), objects.collect::<Vec<_>>())
    }))
    .expect("detections");
    let r = evaluate_dataset(ds.as_ref(), &dets, &opts()).expect("evaluate");
    assert_eq!(r.kitti_frames, 0);
    let count =
        |class: &str| infos.iter().flat_map(|f| &f.objects).filter(|o| o.name.eq_ignore_ascii_case(class)).count();
    assert_eq!((count("Car"), count("Pedestrian"), count("Cyclist")), (5, 2, 1));
    check(&r, |class, _| count(class));
}

/// The breakdown of ground truth against itself on real frames: the report's moderate AP, every
/// counted box found and placed exactly (camera boxes back through the calibration on KITTI).
fn check_breakdown(r: &EvalReport, b: &Breakdown) {
    assert_eq!(b.classes.len(), r.overall.classes.len());
    for (rc, bc) in r.overall.classes.iter().zip(&b.classes) {
        let strict = &rc.sets[0];
        let ap = |v: f64| (rc.num_gt[1] > 0).then_some(v);
        assert_eq!(bc.all.ap_bev_r40_pct, ap(strict.bev.r40[1]), "{}", rc.class);
        assert_eq!(bc.all.ap_3d_r40_pct, ap(strict.d3.r40[1]), "{}", rc.class);
        assert_eq!((bc.all.num_gt, bc.all.found_bev, bc.all.found_3d), (rc.num_gt[1], rc.num_gt[1], rc.num_gt[1]));
        assert_eq!(bc.by_distance.iter().map(|d| d.result.found_3d).sum::<usize>(), rc.num_gt[1], "{}", rc.class);
        assert_eq!(bc.by_points.iter().map(|p| p.result.num_gt).sum::<usize>() + bc.gt_without_points, rc.num_gt[1]);
        assert_eq!((bc.misplaced.missed_bev, bc.misplaced.missed_3d), (0, 0));
        assert_eq!(bc.localisation.num_pairs, rc.num_gt[1]);
        if let Some(e) = &bc.localisation.errors {
            for a in [e.x_m, e.y_m, e.z_m, e.dx_m, e.dy_m, e.dz_m, e.heading_rad] {
                assert!(a.mean_abs < 1e-6, "{}: {e:?}", rc.class);
            }
        }
    }
}

#[test]
fn kitti_breakdown_of_ground_truth_against_itself() {
    let Some(data) = shared() else { return };
    let root = data.join("kitti/training");
    let ds = pi3det_data::open(&root).expect("open KITTI");
    let (_dir, dets, _) = kitti_labels_as_results(&root);
    let r = evaluate_dataset(ds.as_ref(), &dets, &opts()).expect("evaluate");
    let b = breakdown_dataset(ds.as_ref(), &dets, &opts()).expect("breakdown");
    check_breakdown(&r, &b);
}

#[test]
fn pi3det_sample_breakdown_of_ground_truth_against_itself() {
    let Some(data) = shared() else { return };
    let ds = pi3det_data::open(&data.join("pi3det_sample")).expect("open Pi3DET sample");
    let infos: Vec<FrameInfo> = (0..ds.len()).map(|i| ds.info(i).expect("info")).collect();
    let dets = Detections::from_objects(infos.iter().map(|f| {
        let objects = f.objects.iter().enumerate().map(|(k, o)| {
            let mut o = o.clone();
            o.score = Some(0.9 - k as f64 * 0.01);
            o
        });
        (f.id.clone(), objects.collect::<Vec<_>>())
    }))
    .expect("detections");
    let r = evaluate_dataset(ds.as_ref(), &dets, &opts()).expect("evaluate");
    let b = breakdown_dataset(ds.as_ref(), &dets, &opts()).expect("breakdown");
    check_breakdown(&r, &b);
    // The sample stores no num_points_in_gt: its boxes are in no points bin, and said to be.
    for c in &b.classes {
        assert_eq!(c.gt_without_points, c.all.num_gt, "{}", c.class);
    }
}

#[test]
fn nuscenes_breakdown_bins_by_stored_point_counts() {
    let Some(data) = shared() else { return };
    let ds = pi3det_data::open(&data.join("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl")).expect("open nuScenes");
    let infos: Vec<FrameInfo> = (0..ds.len()).map(|i| ds.info(i).expect("info")).collect();
    let dets = Detections::from_objects(infos.iter().map(|f| {
        let objects = f.objects.iter().enumerate().map(|(k, o)| {
            let mut o = o.clone();
            o.score = Some(0.9 - k as f64 * 0.001);
            o
        });
        (f.id.clone(), objects.collect::<Vec<_>>())
    }))
    .expect("detections");
    let o = EvalOptions { classes: vec!["Car".into(), "Pedestrian".into()], ..EvalOptions::default() };
    let r = evaluate_dataset(ds.as_ref(), &dets, &o).expect("evaluate");
    let b = breakdown_dataset(ds.as_ref(), &dets, &o).expect("breakdown");
    check_breakdown(&r, &b);
    for c in &b.classes {
        // num_lidar_pts per box, counted straight from the info file, against the bins.
        let counts: Vec<u32> = infos
            .iter()
            .flat_map(|f| &f.objects)
            .filter(|x| x.name.eq_ignore_ascii_case(&c.class))
            .map(|x| x.num_points.expect("nuScenes stores num_lidar_pts"))
            .collect();
        assert!(!counts.is_empty(), "{}", c.class);
        let n = |lo: u32, hi: u32| counts.iter().filter(|&&k| (lo..=hi).contains(&k)).count();
        let bins: Vec<usize> = c.by_points.iter().map(|p| p.result.num_gt).collect();
        assert_eq!(bins, [n(0, 20), n(21, 100), n(101, u32::MAX)], "{}", c.class);
        assert_eq!(c.gt_without_points, 0);
        for p in c.by_points.iter().filter(|p| p.result.num_gt > 0) {
            assert_eq!(p.result.recall_3d, Some(1.0), "{}: {p:?}", c.class);
        }
    }
}
