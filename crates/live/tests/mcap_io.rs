//! ROS 2 bags in, Foxglove MCAP out. The bag of the cross-check is written by the Python
//! `mcap-ros2-support` package (three PointCloud2 layouts and a String topic); the output is
//! read back by the Python `mcap` reader and decoded with `foxglove-schemas-protobuf`. Both
//! skip with a message where `scripts/setup-mcap` could not install them.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use pi3det_data::{Frame, FrameInfo, Object, PointCloud};
use pi3det_geometry::Box3d;
use pi3det_live::sink::mcap_out::{DETECTIONS_TOPIC, POINTS_TOPIC};
use pi3det_live::sink::FrameLatency;
use pi3det_live::source::mcap_bag::McapSource;
use pi3det_live::source::pointcloud2::{from_xyzi, PointCloud2};
use pi3det_live::{open_sink, Flow, LiveFrame, SinkSpec, Source};

fn python() -> Option<PathBuf> {
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let ok = py.exists()
        && Command::new(&py)
            .args(["-c", "import mcap, mcap_ros2, foxglove_schemas_protobuf"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false);
    if !ok {
        eprintln!(
            "SKIP: {} lacks mcap / mcap-ros2-support / foxglove-schemas-protobuf; run scripts/setup-mcap",
            py.display()
        );
    }
    ok.then_some(py)
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

fn read_all(src: &mut McapSource) -> Vec<LiveFrame> {
    let mut out = Vec::new();
    src.run(
        &mut |f| {
            out.push(f);
            Flow::Continue
        },
        &AtomicBool::new(false),
    )
    .unwrap();
    out
}

/// A bag written by the mcap crate with our CDR encoder (no Python needed).
fn write_bag(path: &Path, clouds: &[PointCloud2], other_topic: bool) {
    let mut w = mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(path).unwrap())).unwrap();
    let s = w.add_schema("sensor_msgs/msg/PointCloud2", "ros2msg", b"").unwrap();
    let c = w.add_channel(s, "/points", "cdr", &Default::default()).unwrap();
    let s2 = w.add_schema("sensor_msgs/msg/Imu", "ros2msg", b"").unwrap();
    let c2 = w.add_channel(s2, "/imu", "cdr", &Default::default()).unwrap();
    for (k, m) in clouds.iter().enumerate() {
        let h = mcap::records::MessageHeader {
            channel_id: c,
            sequence: k as u32,
            log_time: m.stamp_ns,
            publish_time: m.stamp_ns,
        };
        w.write_to_known_channel(&h, &m.encode()).unwrap();
        if other_topic {
            let h = mcap::records::MessageHeader { channel_id: c2, ..h };
            w.write_to_known_channel(&h, &[0, 1, 0, 0]).unwrap();
        }
    }
    w.finish().unwrap();
}

#[test]
fn a_bag_written_here_reads_back_with_its_points() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("b.mcap");
    let clouds: Vec<PointCloud2> = (0..3)
        .map(|k| from_xyzi(&[[k as f32, 1.0, 2.0, 0.5], [3.0, -4.0, 0.25, 0.0]], 1_000_000_000 * (k + 1), "lidar"))
        .collect();
    write_bag(&bag, &clouds, true);
    let mut src = McapSource::open(&bag, None, None).unwrap();
    assert_eq!(src.topic(), "/points");
    let frames = read_all(&mut src);
    assert_eq!(frames.len(), 3);
    for (f, c) in frames.iter().zip(&clouds) {
        assert_eq!(f.stamp_ns, c.stamp_ns);
        assert_eq!(f.frame.points, c.to_points().unwrap().0);
    }
}

#[test]
fn bad_bags_and_topics_say_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("b.mcap");
    write_bag(&bag, &[from_xyzi(&[[0.0; 4]], 1, "f")], true);
    let err =
        |topic: Option<&str>, path: &Path| McapSource::open(path, topic, None).err().expect("an error").to_string();
    let e = err(Some("/velodyne_points"), &bag);
    assert!(e.contains("no topic '/velodyne_points'") && e.contains("/points (sensor_msgs/msg/PointCloud2)"), "{e}");
    let e = err(Some("/imu"), &bag);
    assert!(e.contains("carries sensor_msgs/msg/Imu"), "{e}");
    let junk = dir.path().join("junk.mcap");
    std::fs::write(&junk, b"not an mcap file at all").unwrap();
    assert!(err(None, &junk).contains("not a readable MCAP"), "{}", err(None, &junk));
    assert!(err(None, &dir.path().join("missing.mcap")).contains("missing.mcap"));
    // A cloud without z fails at its message, naming it.
    let mut noz = from_xyzi(&[[0.0; 4]], 5, "f");
    noz.fields.retain(|f| f.name != "z");
    let bag2 = dir.path().join("noz.mcap");
    write_bag(&bag2, &[noz], false);
    let mut src = McapSource::open(&bag2, Some("/points"), None).unwrap();
    let e = src.run(&mut |_| Flow::Continue, &AtomicBool::new(false)).unwrap_err().to_string();
    assert!(e.contains("noz.mcap") && e.contains("message 0") && e.contains("no 'z' field"), "{e}");
}

#[test]
fn a_bag_written_by_mcap_ros2_support_gives_the_right_points() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (bag, expected) = (dir.path().join("ros2.mcap"), dir.path().join("expected.json"));
    let out = Command::new(&py).arg(fixture("write_ros2_bag.py")).args([&bag, &expected]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let expected: Vec<Vec<[f64; 4]>> = serde_json::from_slice(&std::fs::read(&expected).unwrap()).unwrap();
    let mut src = McapSource::open(&bag, None, None).unwrap();
    assert_eq!(src.topic(), "/os_cloud_node/points");
    let frames = read_all(&mut src);
    assert_eq!(frames.len(), expected.len());
    for (k, (f, exp)) in frames.iter().zip(&expected).enumerate() {
        assert_eq!(f.frame.points.len(), exp.len(), "cloud {k}");
        for (p, e) in f.frame.points.iter().zip(exp) {
            for j in 0..4 {
                assert!((f64::from(p[j]) - e[j]).abs() < 1e-6, "cloud {k}: {p:?} vs {e:?}");
            }
        }
        assert_eq!(f.stamp_ns, (1_700_000_000 + k as u64) * 1_000_000_000 + 250_000_000 * k as u64);
    }
    let e = McapSource::open(&bag, Some("/status"), None).err().unwrap().to_string();
    assert!(e.contains("std_msgs/msg/String"), "{e}");
}

fn live_frame(k: usize) -> LiveFrame {
    let mut info = FrameInfo::new(format!("{k:06}"), PathBuf::new());
    info.timestamp_s = Some(10.0 + k as f64 * 0.1);
    let points = PointCloud::from_xyzi(&[[1.0, 2.0, 3.0, 0.5], [4.0, 5.0, 6.0, 1.0], [0.0, 0.0, 0.0, 0.0]]);
    LiveFrame {
        frame: Frame { info, points },
        stamp_ns: 10_000_000_000 + k as u64 * 100_000_000,
        arrived: Instant::now(),
    }
}

fn objects(k: usize) -> Vec<Object> {
    (0..=k)
        .map(|j| Object {
            score: Some(0.5 + 0.1 * j as f64),
            ..Object::new(
                if j % 2 == 0 { "Car" } else { "Pedestrian" },
                Box3d::new(10.0 + j as f64, -2.0, -0.8, 4.2, 1.8, 1.6, 0.3),
            )
        })
        .collect()
}

#[test]
fn the_output_mcap_holds_scene_updates_the_python_reader_decodes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out/run.mcap");
    let spec: SinkSpec = format!("mcap://{}", path.display()).parse().unwrap();
    let mut sink = open_sink(&spec, false).unwrap();
    for k in 0..3 {
        sink.write(&live_frame(k), &objects(k), &FrameLatency::default()).unwrap();
    }
    sink.finish().unwrap();
    // Never replaced unless asked.
    let e = open_sink(&spec, false).err().unwrap().to_string();
    assert!(e.contains("exists") && e.contains("--overwrite"), "{e}");
    // Rust side: the summary has both channels with Foxglove's schemas.
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut topics: Vec<(String, String)> =
        summary.channels.values().map(|c| (c.topic.clone(), c.schema.as_ref().unwrap().name.clone())).collect();
    topics.sort();
    assert_eq!(
        topics,
        vec![
            (DETECTIONS_TOPIC.into(), "foxglove.SceneUpdate".into()),
            (POINTS_TOPIC.into(), "foxglove.PointCloud".into())
        ]
    );
    let Some(py) = python() else { return };
    let out = Command::new(&py).arg(fixture("read_scene.py")).arg(&path).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let scenes = v["scenes"].as_array().unwrap();
    assert_eq!(scenes.len(), 3);
    for (k, s) in scenes.iter().enumerate() {
        assert_eq!(s["log_time"].as_u64().unwrap(), 10_000_000_000 + k as u64 * 100_000_000);
        assert_eq!(s["frame_id"], "lidar");
        let cubes = s["cubes"].as_array().unwrap();
        assert_eq!(cubes.len(), k + 1);
        for (c, o) in cubes.iter().zip(objects(k)) {
            let c: Vec<f64> = c.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
            let b = o.box3d;
            let heading = 2.0 * c[6].atan2(c[7]);
            for (a, e) in c[..6].iter().zip([b.x, b.y, b.z, b.dx, b.dy, b.dz]) {
                assert!((a - e).abs() < 1e-9, "{c:?} vs {b:?}");
            }
            assert!((heading - b.heading).abs() < 1e-9);
        }
        assert_eq!(s["texts"][0], "Car 0.50");
    }
    let clouds = v["clouds"].as_array().unwrap();
    assert_eq!(clouds.len(), 3);
    assert_eq!(clouds[0]["points"], 3);
    assert_eq!(clouds[0]["fields"], serde_json::json!(["x", "y", "z", "intensity"]));
}
