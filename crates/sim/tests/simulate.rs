//! End-to-end checks of the simulator: determinism, stored labels, and the paper's three
//! cross-platform discrepancies (Pi3DET §3.3), with fixed seeds and reduced resolution.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use pi3det_data::Platform;
use pi3det_geometry::PoseExt;
use pi3det_sim::{export, ExportOptions, PlatformPlan, Sequence, SequenceSpec, SimConfig, StatsAccumulator};

/// OS1-64 at 256 columns: the same beams, a quarter of the rays.
fn small_config() -> SimConfig {
    let mut cfg = SimConfig::default();
    cfg.sensor.columns = 256;
    cfg
}

fn files_under(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.strip_prefix(root).unwrap().to_path_buf(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

fn export_with_threads(cfg: &SimConfig, plans: &[PlatformPlan], out: &Path, seed: u64, threads: usize) {
    let opts = ExportOptions {
        out: out.to_path_buf(),
        seed,
        overwrite: false,
        per_platform_folders: true,
        layout: None,
        stratify_layouts: false,
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| export(cfg, plans, &opts, &mut |_, _| {})).unwrap();
}

#[test]
fn same_seed_gives_byte_identical_files_whatever_the_thread_count() {
    let cfg = small_config();
    let plans = [
        PlatformPlan { platform: Platform::Vehicle, sequences: 2, frames: 3, val_sequences: 1 },
        PlatformPlan { platform: Platform::Drone, sequences: 1, frames: 2, val_sequences: 0 },
        PlatformPlan { platform: Platform::Quadruped, sequences: 1, frames: 2, val_sequences: 0 },
    ];
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (dir.path().join("a"), dir.path().join("b"), dir.path().join("c"));
    export_with_threads(&cfg, &plans, &a, 7, 1);
    export_with_threads(&cfg, &plans, &b, 7, 3);
    export_with_threads(&cfg, &plans, &c, 8, 2);
    let (fa, fb, fc) = (files_under(&a), files_under(&b), files_under(&c));
    assert_eq!(fa.len(), 6 + 2 + 2 + 4, "{:?}", fa.keys().collect::<Vec<_>>());
    assert!(fa.contains_key(Path::new("vehicle/train/pi3det_infos_train.pkl")));
    assert!(fa.contains_key(Path::new("vehicle/val/pi3det_infos_val.pkl")));
    assert!(fa.contains_key(Path::new("drone/train/training/point_cloud/0000001.bin")));
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (path, bytes) in &fa {
        assert!(bytes == &fb[path], "{} differs between runs with the same seed", path.display());
    }
    let differing = fa.iter().filter(|(p, bytes)| fc.get(*p) != Some(bytes)).count();
    assert!(differing >= fa.len() - 1, "another seed should change the data");
}

#[test]
fn stored_boxes_hold_their_stored_point_counts() {
    let cfg = small_config();
    let plans: Vec<PlatformPlan> = [Platform::Vehicle, Platform::Drone, Platform::Quadruped]
        .into_iter()
        .map(|p| PlatformPlan { platform: p, sequences: 3, frames: 3, val_sequences: 1 })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let opts = ExportOptions {
        out: dir.path().to_path_buf(),
        seed: 3,
        overwrite: false,
        per_platform_folders: true,
        layout: None,
        stratify_layouts: false,
    };
    let report = export(&cfg, &plans, &opts, &mut |_, _| {}).unwrap();
    assert_eq!(report.splits.len(), 6);
    let mut boxes = 0;
    for platform in [Platform::Vehicle, Platform::Drone, Platform::Quadruped] {
        let mut seqs: BTreeMap<&str, BTreeSet<String>> = BTreeMap::new();
        for split in ["train", "val"] {
            let ds = pi3det_data::open(&dir.path().join(platform.as_str()).join(split)).unwrap();
            assert_eq!(ds.len(), if split == "train" { 6 } else { 3 });
            for i in 0..ds.len() {
                let frame = ds.load(i).unwrap();
                let info = &frame.info;
                assert_eq!(info.platform, platform);
                let seq = info.sequence.clone().unwrap();
                assert!(seq.starts_with(platform.as_str()));
                seqs.entry(split).or_default().insert(seq);
                assert!(info.timestamp_s.is_some());
                let pose = info.world_from_lidar.expect("every frame has a pose");
                assert!(pose.roll_pitch_yaw().roll_rad.abs() < 0.6);
                assert!(frame.points.len() > 1000);
                for o in &info.objects {
                    let stored = o.num_points.expect("num_points_in_gt stored") as usize;
                    assert!(stored >= 5, "{} has {stored} points", o.name);
                    assert_eq!(o.box3d.count_points(frame.points.xyz_f64()), stored, "{} in {}", o.name, info.id);
                    assert!(o.name == "Car" || o.name == "Pedestrian");
                    assert!(o.box3d.x.hypot(o.box3d.y) <= cfg.sensor.range_max_m);
                    assert!((-std::f64::consts::PI..std::f64::consts::PI).contains(&o.box3d.heading));
                    if o.name == "Pedestrian" {
                        assert!((1.5..=1.95).contains(&o.box3d.dz));
                    }
                    boxes += 1;
                }
            }
        }
        // Split by sequence, never by frame.
        assert!(seqs["train"].is_disjoint(&seqs["val"]), "{platform}: {seqs:?}");
        assert_eq!(seqs["train"].len(), 2);
    }
    assert!(boxes > 50, "only {boxes} boxes");
}

#[test]
fn labels_are_world_boxes_seen_from_the_sensor() {
    let cfg = small_config();
    // The first drone sequence (tilted sensor) with labels in its last frame.
    let (seq, frame) = (0..10)
        .map(|index| {
            let seq = Sequence::generate(
                &cfg,
                SequenceSpec { platform: Platform::Drone, index, frames: 4, seed: 5, layout: None },
            )
            .unwrap();
            let frame = seq.render(3);
            (seq, frame)
        })
        .find(|(_, f)| f.objects.len() >= 3)
        .expect("a drone frame with labels");
    let t = 3.0 / cfg.sensor.rate_hz;
    for o in &frame.objects {
        // Back in the world, the centre is an actor's centre standing on its support.
        let c = frame.world_from_lidar.transform_point(&o.box3d.center());
        let found = seq.actors.iter().any(|a| {
            let (xy, _) = a.pose_at(t);
            let ground = seq.scene.support_height(xy);
            (xy[0] - c.x).hypot(xy[1] - c.y) < 1e-3 && (ground + 0.5 * a.size_m[2] - c.z).abs() < 1e-3
        });
        assert!(found, "{o:?} matches no actor");
    }
}

struct Summary {
    roll_std: f64,
    pitch_std: f64,
    elevation_median: f64,
    share_above: f64,
    rel_pitch_median: f64,
    boxes: usize,
}

fn summarise(platform: Platform, sequences: u32, frames: u32) -> Summary {
    let cfg = small_config();
    let mut acc = StatsAccumulator::new(5);
    for index in 0..sequences {
        let seq = Sequence::generate(&cfg, SequenceSpec { platform, index, frames, seed: 2024, layout: None }).unwrap();
        for f in 0..seq.len() {
            acc.add(&seq.render(f).to_frame("x", platform, &seq.name));
        }
    }
    let s = acc.finish();
    assert_eq!(s.frames, (sequences * frames) as usize);
    eprintln!("{platform}: {s:?}");
    Summary {
        roll_std: s.roll_std_deg,
        pitch_std: s.pitch_std_deg,
        elevation_median: s.elevation_median_m,
        share_above: s.share_above_sensor,
        rel_pitch_median: s.relative_pitch_median_deg,
        boxes: s.boxes,
    }
}

#[test]
fn the_three_cross_platform_discrepancies() {
    // 300 frames per platform, spread over twelve sequences: layouts, heights and speeds are drawn
    // per sequence, so the platforms' own mixes of places show, not one lucky scene.
    let v = summarise(Platform::Vehicle, 12, 25);
    let d = summarise(Platform::Drone, 12, 25);
    let q = summarise(Platform::Quadruped, 12, 25);
    assert!(v.boxes > 100 && d.boxes > 100 && q.boxes > 100);

    // 1. Ego motion: vehicles are steady, drones and quadrupeds jitter.
    assert!(v.roll_std < 2.0 && v.pitch_std < 2.0, "vehicle roll/pitch std {} {}", v.roll_std, v.pitch_std);
    for (name, s) in [("drone", &d), ("quadruped", &q)] {
        assert!(s.roll_std > 5.0 && s.pitch_std > 5.0, "{name} roll/pitch std {} {}", s.roll_std, s.pitch_std);
    }

    // 2. Point elevation relative to the sensor, levelled: vehicle a little below, drone far
    //    below, quadruped with the largest share of points above the sensor.
    assert!((-2.5..0.0).contains(&v.elevation_median), "vehicle elevation median {}", v.elevation_median);
    assert!(
        d.elevation_median < -4.0 && d.elevation_median < 2.0 * v.elevation_median,
        "drone elevation median {}",
        d.elevation_median
    );
    assert!(
        q.share_above > v.share_above + 0.05 && q.share_above > d.share_above + 0.05,
        "share above: q {} v {} d {}",
        q.share_above,
        v.share_above,
        d.share_above
    );
    assert!(q.elevation_median > v.elevation_median, "quadruped points sit higher relative to its sensor");

    // 3. Relative pitch to targets: drone strongly downward, quadruped upward, vehicle near level.
    assert!(d.rel_pitch_median < -6.0, "drone relative pitch {}", d.rel_pitch_median);
    assert!(q.rel_pitch_median > 0.0, "quadruped relative pitch {}", q.rel_pitch_median);
    assert!(
        v.rel_pitch_median.abs() < 4.0 && v.rel_pitch_median > d.rel_pitch_median + 4.0,
        "vehicle relative pitch {}",
        v.rel_pitch_median
    );
}

#[test]
fn splits_written_with_their_own_seeds_match_whole_exports_and_stratified_splits_hold_the_mix() {
    use pi3det_sim::{export_split, stratified_layouts};
    let cfg = small_config();
    let plan = PlatformPlan { platform: Platform::Vehicle, sequences: 5, frames: 2, val_sequences: 3 };
    let dir = tempfile::tempdir().unwrap();
    let whole = |seed, name: &str| {
        let out = dir.path().join(name);
        export_with_threads(&cfg, &[plan], &out, seed, 1);
        files_under(&out)
    };
    let (seed_4, seed_9) = (whole(4, "s4"), whole(9, "s9"));
    // Train from seed 4, val from seed 9, written split by split into one folder.
    let mixed = dir.path().join("mixed");
    let opts = |seed| ExportOptions {
        out: mixed.clone(),
        seed,
        overwrite: false,
        per_platform_folders: true,
        layout: None,
        stratify_layouts: false,
    };
    let train = export_split(&cfg, &plan, "train", &opts(4), &mut |_, _| {}).unwrap().unwrap();
    let val = export_split(&cfg, &plan, "val", &opts(9), &mut |_, _| {}).unwrap().unwrap();
    assert_eq!((train.frames, val.frames), (4, 6));
    let m = files_under(&mixed);
    for (path, bytes) in &m {
        let from = if path.starts_with("vehicle/train") { &seed_4 } else { &seed_9 };
        assert!(from.get(path) == Some(bytes), "{} differs from the whole export of its seed", path.display());
    }
    assert_eq!(m.len(), seed_4.len());
    assert!(export_split(&cfg, &plan, "test", &opts(4), &mut |_, _| {}).is_err(), "unknown split");
    let none = PlatformPlan { val_sequences: 0, ..plan };
    assert!(export_split(&cfg, &none, "val", &opts(4), &mut |_, _| {}).unwrap().is_none());

    // Stratified: the val sequences' layouts follow the fixed schedule, whatever the seed.
    let want: Vec<String> =
        stratified_layouts(cfg.vehicle.layout_weights, 3).iter().map(|l| l.as_str().to_string()).collect();
    for seed in [1, 2] {
        let o = ExportOptions { out: dir.path().join(format!("strat{seed}")), stratify_layouts: true, ..opts(seed) };
        let val = export_split(&cfg, &plan, "val", &o, &mut |_, _| {}).unwrap().unwrap();
        let got: Vec<String> = val.sequences.iter().map(|s| s.split('_').nth(1).unwrap().to_string()).collect();
        assert_eq!(got, want, "seed {seed}: {:?}", val.sequences);
    }
}
