//! The ground fit on real scans: KITTI (Velodyne HDL-64 on a VW Passat, mounted 1.73 m above the
//! road) and a nuScenes LIDAR_TOP sweep (lidar2ego puts the sensor 1.84 m above the ego origin on
//! the ground).

use std::path::{Path, PathBuf};

use pi3det_analysis::{estimate_ground, GroundConfig};

fn shared_data() -> PathBuf {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data"));
    assert!(
        p.join("kitti/training/velodyne").is_dir(),
        "shared test data missing: expected {} (the repository's ../shared/data with kitti/ and nuscenes_demo/)",
        p.display()
    );
    p
}

fn ground_of(path: &Path) -> Vec<(String, pi3det_analysis::GroundEstimate)> {
    let ds = pi3det_data::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (0..ds.len())
        .map(|i| {
            let f = ds.load(i).unwrap();
            let e = estimate_ground(f.points.xyz_f64(), &GroundConfig::default())
                .unwrap_or_else(|e| panic!("{}: {e}", f.info.id));
            (f.info.id.clone(), e)
        })
        .collect()
}

fn log(name: &str, est: &[(String, pi3det_analysis::GroundEstimate)]) {
    for (id, e) in est {
        eprintln!(
            "{name} {id}: height {:.3} m roll {:.2}° pitch {:.2}° inliers {} / {} ({:.2}) confidence {:.2} rms {:.3} m",
            e.height_m,
            e.roll_rad.to_degrees(),
            e.pitch_rad.to_degrees(),
            e.inliers,
            e.candidates,
            e.inlier_ratio,
            e.confidence,
            e.rms_m
        );
    }
}

/// KITTI's Velodyne is mounted 1.73 m above the road (KITTI setup paper); the test prints each
/// frame's estimate. Tolerances: each frame within ±0.08 m — the nominal height is for a car at
/// rest on flat ground; road camber, kerbs and the car's suspension move the local ground plane by
/// several cm, and another plane fit (RANSAC) lands up to that much higher; the mean of six frames
/// within ±0.04 m. Tilt at most 4°: the sensor is mounted level, and roads bank and slope by a few
/// degrees.
#[test]
fn kitti_sensor_height_and_tilt() {
    let est = ground_of(&shared_data().join("kitti/training"));
    log("kitti", &est);
    assert_eq!(est.len(), 6);
    for (id, e) in &est {
        assert!((e.height_m - 1.73).abs() <= 0.08, "{id}: height {:.3} m", e.height_m);
        assert!(e.roll_rad.to_degrees().abs() <= 4.0 && e.pitch_rad.to_degrees().abs() <= 4.0, "{id}: {e:?}");
        assert!(e.confidence > 0.8 && e.inlier_ratio > 0.2, "{id}: {e:?}");
    }
    let mean = est.iter().map(|(_, e)| e.height_m).sum::<f64>() / est.len() as f64;
    assert!((mean - 1.73).abs() <= 0.04, "mean height {mean:.3} m");
}

/// nuScenes LIDAR_TOP: lidar2ego translation z = 1.84 m with the ego origin on the ground (rear
/// axle). Tolerance ±0.05 m: one frame on an urban road, same reasons as KITTI but flatter ground
/// near the car. Tilt ≤ 3°.
#[test]
fn nuscenes_sensor_height() {
    let est = ground_of(&shared_data().join("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl"));
    log("nuscenes", &est);
    assert_eq!(est.len(), 1);
    let e = &est[0].1;
    assert!((e.height_m - 1.84).abs() <= 0.05, "height {:.3} m", e.height_m);
    assert!(e.roll_rad.to_degrees().abs() <= 3.0 && e.pitch_rad.to_degrees().abs() <= 3.0, "{e:?}");
    assert!(e.confidence > 0.8, "{e:?}");
}

/// The same KITTI frames through the Pi3DET-layout copy and the whole pipeline: same heights (the
/// pipeline calls the same function), and `pi3det stats`-style outputs on real data.
#[test]
fn pi3det_sample_through_the_pipeline() {
    use pi3det_analysis::analyze::{analyze, Input, NoProgress, StatsConfig};
    let ds = pi3det_data::open(&shared_data().join("pi3det_sample")).unwrap();
    let inputs = [Input { name: "pi3det_sample".into(), dataset: ds.as_ref() }];
    let mut heights = Vec::new();
    let a = analyze(&inputs, &StatsConfig::default(), &NoProgress, &mut |f| {
        heights.push(f.ground.expect("ground").height_m);
        Ok(())
    })
    .unwrap();
    assert_eq!(heights.len(), 6);
    assert!(heights.iter().all(|h| (h - 1.73).abs() <= 0.08), "{heights:?}");
    let g = a.platforms.values().next().unwrap();
    // Vehicle view: most points below the sensor, targets slightly below it.
    assert!(g.elevation.share_above_sensor() < 0.3);
    assert!(g.targets.relative_pitch_deg.quantile(0.5).unwrap() < 0.0);
}
