//! Inference levels frames to the sensor height training recorded (issue 44): the same scene in
//! the sensor frame and in a vehicle frame (shifted up) reaches the network identically, a
//! checkpoint written before the height was recorded still loads (and is not levelled), and a
//! frame whose intensity was lost gets the training mean.

use pi3det_data::{Frame, FrameInfo, Object, PointCloud};
use pi3det_geometry::Box3d;
use pi3det_nn::checkpoint;
use pi3det_nn::config::TrainedOn;
use pi3det_nn::preprocess::{Level, Preprocessor};
use pi3det_nn::testing::tiny_detector;
use pi3det_nn::{Detector, DetectorConfig};
use tch::Device;

const SENSOR_HEIGHT_M: f64 = 1.9;

/// A flat ground `height` below the sensor (a 0.5 m lattice out to 25 m) and a car standing on
/// it 9 m ahead, its faces sampled every 0.1 m; `lift` moves everything up (a vehicle frame whose
/// origin is `lift` below the sensor).
fn scene(lift: f64, intensity: impl Fn(usize) -> f32) -> Frame {
    let ground_z = -SENSOR_HEIGHT_M + lift;
    let mut pts = Vec::new();
    for i in -50..=50 {
        for j in -50..=50 {
            let (x, y) = (i as f64 * 0.5, j as f64 * 0.5);
            let r = (x * x + y * y).sqrt();
            if (1.5..25.0).contains(&r) && !(7.0..11.5).contains(&x) {
                pts.push([x, y, ground_z]);
            }
        }
    }
    let car = Box3d::new(9.0, 0.0, ground_z + 0.8, 4.2, 1.8, 1.6, 0.0);
    for a in 0..=42 {
        for h in 0..=16 {
            pts.push([car.x - 2.1 + a as f64 * 0.1, -0.9, ground_z + h as f64 * 0.1]);
            pts.push([car.x - 2.1, -0.9 + a as f64 * 0.9 / 21.0, ground_z + h as f64 * 0.1]);
        }
    }
    let data: Vec<[f32; 4]> =
        pts.iter().enumerate().map(|(k, p)| [p[0] as f32, p[1] as f32, p[2] as f32, intensity(k)]).collect();
    let mut info = FrameInfo::new(format!("lift_{lift}"), format!("/nowhere/lift_{lift}.bin").into());
    info.objects.push(Object::new("Car", car));
    Frame { info, points: PointCloud::from_xyzi(&data) }
}

fn trained_config() -> DetectorConfig {
    let mut cfg = tiny_detector(25.6, 0.8);
    cfg.trained_on = Some(TrainedOn { sensor_height_m: Some(SENSOR_HEIGHT_M), intensity_mean: Some(0.3) });
    cfg
}

fn levelled(cfg: &DetectorConfig, level: Level) -> Preprocessor {
    let prep = Preprocessor::new(cfg).unwrap();
    match level.transform(cfg).unwrap() {
        Some(v) => prep.with_frame_transform(v),
        None => prep,
    }
}

#[test]
fn sensor_frame_and_vehicle_frame_reach_the_network_alike() {
    let cfg = trained_config();
    let varied = |k: usize| (k % 7) as f32 / 10.0;
    let (sensor, vehicle) = (scene(0.0, varied), scene(1.55, varied));
    // Fresh preprocessors: VPP caches one transform per point file.
    let a = levelled(&cfg, Level::Trained).sample(&sensor, 0);
    let b = levelled(&cfg, Level::Trained).sample(&vehicle, 0);
    assert_eq!(a.points.len(), b.points.len());
    let worst = a
        .points
        .iter()
        .zip(&b.points)
        .map(|(p, q)| (0..4).map(|i| (p[i] - q[i]).abs()).fold(0.0f32, f32::max))
        .fold(0.0f32, f32::max);
    // Each frame's ground is fitted on its own (RANSAC, least squares): the two fits agree to
    // millimetres, not bits.
    assert!(worst < 1e-2, "levelled points differ by up to {worst} m");
    assert!((a.boxes[0].z - b.boxes[0].z).abs() < 1e-2, "{:?} vs {:?}", a.boxes[0], b.boxes[0]);
    // The car stands on z ≈ 0 in the detector's frame (its anchors' bottom).
    assert!((a.boxes[0].z - a.boxes[0].dz / 2.0).abs() < 0.05, "{:?}", a.boxes[0]);
    // Without levelling the vehicle frame sits 1.55 m too high.
    let plain = levelled(&cfg, Level::Off).sample(&vehicle, 0);
    assert!((plain.boxes[0].z - a.boxes[0].z - 1.55).abs() < 1e-6);
}

#[test]
fn a_frame_without_ground_keeps_the_plain_shift_and_is_counted() {
    let cfg = trained_config();
    // A handful of returns (a sensor facing the sky): too few for any plane.
    let mut sky = scene(0.0, |_| 0.5);
    let mut k = 0;
    sky.points.retain(|_| {
        k += 1;
        k % 400 == 0
    });
    assert!(sky.points.len() < 100);
    let v = Level::Height(SENSOR_HEIGHT_M).transform(&cfg).unwrap().unwrap();
    let prep = Preprocessor::new(&cfg).unwrap().with_frame_transform(v.clone());
    let s = prep.sample(&sky, 0);
    let plain = Preprocessor::new(&cfg).unwrap().sample(&sky, 0);
    assert_eq!(s.points, plain.points);
    assert_eq!(v.counts().no_ground, 1);
}

#[test]
fn a_checkpoint_without_a_training_height_still_loads_unlevelled() {
    let dir = tempfile::tempdir().unwrap();
    let old = tiny_detector(25.6, 0.8);
    assert!(old.trained_on.is_none());
    let det = Detector::new(&old, Device::Cpu).unwrap();
    let path = dir.path().join("old.safetensors");
    checkpoint::save(&path, &det, None, &Default::default()).unwrap();
    let ck = checkpoint::load(&path).unwrap();
    assert_eq!(ck.config.trained_on, None);
    assert_eq!(Level::Trained.height_m(&ck.config), None);
    assert!(Level::Trained.describe(&ck.config).contains("records no training sensor height"));
    let mut fresh = Detector::new(&ck.config, Device::Cpu).unwrap();
    ck.load_into(&mut fresh, &path).unwrap();
    // And one that records it round-trips it.
    let det = Detector::new(&trained_config(), Device::Cpu).unwrap();
    checkpoint::save(&path, &det, None, &Default::default()).unwrap();
    assert_eq!(checkpoint::load(&path).unwrap().config.trained_on, trained_config().trained_on);
    assert_eq!(Level::Trained.height_m(&trained_config()), Some(SENSOR_HEIGHT_M));
}

#[test]
fn lost_intensity_reaches_the_network_as_the_training_mean() {
    let cfg = trained_config();
    let lost = levelled(&cfg, Level::Off).sample(&scene(0.0, |_| 1.0), 0);
    assert!(lost.points.iter().all(|p| p[3] == 0.3));
    let kept = levelled(&cfg, Level::Off).sample(&scene(0.0, |k| (k % 3) as f32 / 3.0), 0);
    assert!(kept.points.iter().any(|p| p[3] == 0.0));
    // A config that recorded nothing leaves intensity alone.
    let old = levelled(&tiny_detector(25.6, 0.8), Level::Off).sample(&scene(0.0, |_| 1.0), 0);
    assert!(old.points.iter().all(|p| p[3] == 1.0));
}
