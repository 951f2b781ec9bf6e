//! The statistics pipeline on small hand-built frames and datasets with known answers.

use nalgebra::Point3;
use pi3det_analysis::analyze::{analyze, frame_stats, Input, NoProgress, StatsConfig};
use pi3det_analysis::elevation::LevelSource;
use pi3det_analysis::{plots, report, FrameAttitude};
use pi3det_data::pi3det::Pi3detWriter;
use pi3det_data::{Frame, FrameInfo, Object, Platform, PointCloud};
use pi3det_geometry::{Box3d, Pose, PoseExt};

/// Level ground (world z = 0) on rings 2–40 m around the sensor, plus `inside` points in a grid
/// strictly inside each world box, seen from `world_from_lidar`. Boxes are returned in the LiDAR
/// frame as stored labels are.
fn frame(id: &str, world_from_lidar: Pose, world_boxes: &[(&str, Box3d)], inside: usize) -> Frame {
    let lidar_from_world = world_from_lidar.inverse();
    let c = world_from_lidar.translation.vector;
    let mut world = Vec::new();
    for ring in 0..48 {
        let r = 2.0 + ring as f64 * 0.8;
        for k in 0..240 {
            let a = k as f64 * std::f64::consts::TAU / 240.0;
            world.push([c.x + r * a.cos(), c.y + r * a.sin(), 0.0]);
        }
    }
    for (_, b) in world_boxes {
        let n = (inside as f64).cbrt().ceil() as usize;
        let mut added = 0;
        'fill: for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    if added == inside {
                        break 'fill;
                    }
                    let f = |t: usize| (t as f64 + 0.5) / n as f64 - 0.5;
                    let (u, v, w) = (f(i) * b.dx * 0.9, f(j) * b.dy * 0.9, f(k) * b.dz * 0.9);
                    let (s, co) = b.heading.sin_cos();
                    world.push([b.x + co * u - s * v, b.y + s * u + co * v, b.z + w]);
                    added += 1;
                }
            }
        }
    }
    let pts: Vec<[f32; 4]> = world
        .iter()
        .map(|p| {
            let q = lidar_from_world.transform_point(&Point3::new(p[0], p[1], p[2]));
            [q.x as f32, q.y as f32, q.z as f32, 0.5]
        })
        .collect();
    let mut info = FrameInfo::new(id, format!("{id}.bin").into());
    info.world_from_lidar = Some(world_from_lidar);
    info.objects = world_boxes.iter().map(|(name, b)| Object::new(*name, b.transformed(&lidar_from_world))).collect();
    Frame { info, points: PointCloud::from_xyzi(&pts) }
}

#[test]
fn one_frame_known_answers() {
    // Level vehicle sensor 1.8 m up; a car 10 m ahead (centre 0.85 m up) and a pedestrian 5 m to
    // the left (centre 0.95 m up); both float 5 cm above the ground so that no ground point is in
    // them (the inside test is inclusive).
    let pose = Pose::from_xyz_rpy([0.0, 0.0, 1.8], 0.0, 0.0, 0.0);
    let car = Box3d::new(10.0, 0.0, 0.85, 4.0, 2.0, 1.6, 0.3);
    let ped = Box3d::new(0.0, 5.0, 0.95, 0.6, 0.6, 1.8, 0.0);
    let mut f = frame("000000", pose, &[("Car", car), ("Pedestrian", ped)], 64);
    f.info.platform = Platform::Vehicle;
    let s = frame_stats(&f, &StatsConfig::default(), 1.0);
    let g = &s.stats;
    // Ground fit: exact plane, 1.8 m.
    let e = s.attitude.ground.expect("ground found");
    assert!((e.height_m - 1.8).abs() < 1e-4 && e.roll_rad.abs() < 1e-5 && e.pitch_rad.abs() < 1e-5, "{e:?}");
    assert_eq!(s.attitude.level_source, LevelSource::Pose);
    // Ego motion from the pose.
    assert_eq!(g.ego.roll_deg.count(), 1);
    assert!(g.ego.pitch_deg.moments.mean.abs() < 1e-9);
    // Elevation: ground points at −1.8, box points inside the boxes, all below the sensor.
    assert_eq!(g.elevation.above_sensor, 0);
    assert!((g.elevation.z_level_m.moments.min + 1.8).abs() < 1e-5);
    // Targets: car at ρ = 10, θʳ = atan(−0.95 / 10); pedestrian ρ = 5, θʳ = atan(−0.85 / 5).
    let t = &s.targets;
    assert!((t[0][0] - 10.0).abs() < 1e-9 && (t[0][1] - (-0.095f64).atan().to_degrees()).abs() < 1e-9);
    assert!((t[1][0] - 5.0).abs() < 1e-9 && (t[1][1] - (-0.17f64).atan().to_degrees()).abs() < 1e-9);
    // Boxes: sizes and exactly 64 points in each.
    assert_eq!(g.boxes.classes["Car"].length_m.moments.mean, 4.0);
    assert_eq!(g.boxes.classes["Pedestrian"].height_m.moments.mean, 1.8);
    assert_eq!(g.boxes.points_per_box.moments.mean, 64.0);
    assert_eq!(g.boxes.objects_per_frame.moments.mean, 2.0);
    // Points: 48·240 ground + 128 box points, intensity 0.5.
    assert_eq!(g.points.points_per_frame.moments.mean, (48 * 240 + 128) as f64);
    assert!((g.points.intensity.moments.mean - 0.5).abs() < 1e-12);
}

/// Roll/pitch of frame `k` of a platform's synthetic sequence (radians).
fn attitude(platform: Platform, k: usize) -> (f64, f64) {
    let t = k as f64 * 0.1;
    match platform {
        Platform::Vehicle => (0.01 * (0.5 * t).sin(), 0.015 * (0.3 * t).cos()),
        Platform::Drone => (0.2 * (1.3 * t).sin(), -0.15 * (0.9 * t).cos()),
        _ => (0.25 * (std::f64::consts::TAU * 2.0 * t).sin(), 0.2 * (std::f64::consts::TAU * 2.0 * t).cos()),
    }
}

fn height(platform: Platform) -> f64 {
    match platform {
        Platform::Vehicle => 1.9,
        Platform::Drone => 12.0,
        _ => 0.6,
    }
}

#[test]
fn sequences_of_three_platforms_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let mut roots = Vec::new();
    for platform in Platform::ALL {
        let root = dir.path().join(platform.as_str());
        let mut w = Pi3detWriter::create(&root, "train", false).unwrap();
        for k in 0..12 {
            let (r, p) = attitude(platform, k);
            let pose = Pose::from_xyz_rpy([k as f64, 0.5 * k as f64, height(platform)], r, p, 0.1 * k as f64);
            let ped = Box3d::new(k as f64 + 6.0, 3.0, 0.9, 0.6, 0.6, 1.8, 0.0);
            let mut f = frame(&format!("{}{k:03}", platform.as_str()), pose, &[("Pedestrian", ped)], 27);
            f.info.platform = platform;
            f.info.sequence = Some("seq_a".into());
            f.info.timestamp_s = Some(100.0 + 0.1 * k as f64);
            w.write_frame(&f).unwrap();
        }
        w.finish().unwrap();
        roots.push(root);
    }
    let datasets: Vec<_> = roots.iter().map(|r| pi3det_data::open(r).unwrap()).collect();
    let inputs: Vec<Input> = datasets
        .iter()
        .zip(&roots)
        .map(|(d, r)| Input { name: r.display().to_string(), dataset: d.as_ref() })
        .collect();
    let mut rows: Vec<FrameAttitude> = Vec::new();
    let config = StatsConfig { chunk_frames: 5, ..StatsConfig::default() };
    let a = analyze(&inputs, &config, &NoProgress, &mut |f| {
        rows.push(f.clone());
        Ok(())
    })
    .unwrap();
    assert_eq!(rows.len(), 36);
    assert_eq!(a.platforms.len(), 3);
    assert_eq!(a.sequences.len(), 3);
    // Frames come out in time order within each sequence, every one smoothed.
    for w in rows.windows(2).filter(|w| w[0].input == w[1].input) {
        assert!(w[0].timestamp_s < w[1].timestamp_s);
    }
    assert!(rows.iter().all(|r| r.smoothed.is_some() && r.ground.is_some()));
    for (p, g) in &a.platforms {
        // The ground fit recovers the true roll and pitch (the ground is an exact plane; float32
        // points limit it to ~1e-3°) and the sensor height.
        let med = g.ground.abs_roll_error_deg.quantile(0.5).unwrap();
        let p95 = g.ground.abs_pitch_error_deg.quantile(0.95).unwrap();
        assert!(med < 0.02 && p95 < 0.02, "{p}: roll err median {med}, pitch err p95 {p95}");
        assert!((g.ground.height_m.moments.mean - height(*p)).abs() < 0.01, "{p}");
        assert!(g.ground.smoothed_abs_roll_error_deg.quantile(0.95).unwrap() < 0.5, "{p}");
        // Ego motion: 12 attitudes and 11 steps; the pose roll's spread is the synthetic one.
        assert_eq!(g.ego.roll_deg.count(), 12);
        assert_eq!(g.ego.roll_jitter_deg.count(), 11);
        let truth: Vec<f64> = (0..12).map(|k| attitude(*p, k).0.to_degrees()).collect();
        let mean = truth.iter().sum::<f64>() / 12.0;
        let std = (truth.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 12.0).sqrt();
        assert!((g.ego.roll_deg.moments.std() - std).abs() < 1e-6, "{p}");
        assert_eq!(g.elevation.frames_by_pose, 12);
    }
    // The discrepancy signs: drone targets far below, quadruped targets above, vehicle between.
    let theta = |p: Platform| a.platforms[&p].targets_level.relative_pitch_deg.quantile(0.5).unwrap();
    assert!(theta(Platform::Drone) < -30.0 && theta(Platform::Quadruped) > 0.0);
    assert!(theta(Platform::Vehicle) < 0.0 && theta(Platform::Vehicle) > theta(Platform::Drone));

    // Tables and figures.
    let out = dir.path().join("report");
    let figures = plots::write_figures(&a, &out).unwrap();
    for f in &figures {
        let len = std::fs::metadata(f).unwrap().len();
        assert!(len > 1000, "{} is {len} bytes", f.display());
    }
    assert!(figures.iter().any(|f| f.ends_with("fig2.png")) && figures.iter().any(|f| f.ends_with("fig2.svg")));
    let svg = std::fs::read_to_string(out.join("fig2.svg")).unwrap();
    assert!(svg.contains("Relative pitch") && svg.contains("quadruped"));
    let tables = report::write_tables(&a, &out, &["fig2.png".into()]).unwrap();
    assert_eq!(tables.len(), 6);
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| drone | 12 |") && md.contains("![fig2.png](fig2.png)"), "{md}");
    let csv = std::fs::read_to_string(out.join("platforms.csv")).unwrap();
    assert!(csv.lines().any(|l| l.starts_with("quadruped,ground.abs_roll_error,deg,12,")), "{csv}");
    let seq = std::fs::read_to_string(out.join("sequences.csv")).unwrap();
    assert!(seq.lines().any(|l| l.starts_with("drone,seq_a,1,ego.roll,")));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stats.json")).unwrap()).unwrap();
    assert_eq!(json["platforms"]["vehicle"]["frames"], 12);

    // max_frames takes the first frames of each input.
    let limited =
        analyze(&inputs, &StatsConfig { max_frames: Some(4), ..config }, &NoProgress, &mut |_| Ok(())).unwrap();
    assert_eq!(limited.total.frames, 12);
}

#[test]
fn frames_without_pose_are_levelled_by_the_ground() {
    // A quadruped tilted 12° in pitch, no pose stored: the ground fit levels it, so the pedestrian
    // 4 m ahead appears above the sensor (centre 0.9 m vs sensor 0.6 m).
    let pose = Pose::from_xyz_rpy([0.0, 0.0, 0.6], 0.0, 12f64.to_radians(), 0.0);
    let mut f = frame("q", pose, &[("Pedestrian", Box3d::new(4.0, 0.0, 0.9, 0.6, 0.6, 1.8, 0.0))], 8);
    f.info.world_from_lidar = None;
    let s = frame_stats(&f, &StatsConfig::default(), 1.0);
    assert_eq!(s.attitude.level_source, LevelSource::Ground);
    let level = s.stats.targets_level.relative_pitch_deg.moments.mean;
    assert!((level - (0.3f64 / 4.0).atan().to_degrees()).abs() < 1e-3, "{level}");
    // Seen from the sensor, whose x axis points 12° below the horizon, it is 12° higher still.
    let sensor = s.stats.targets.relative_pitch_deg.moments.mean;
    assert!((sensor - level - 12.0).abs() < 1e-3, "{sensor}");
    assert_eq!(s.stats.ego.roll_deg.count(), 0);
}
