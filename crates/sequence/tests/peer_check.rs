//! Our reader against the Ouster SDK on the same packets: the fixture script writes a synthetic
//! release with h5py (LZF, one sweep per chunk), the oracle decodes it with ouster-sdk's own
//! packet / scan classes and XYZLut, and every point must agree to 1 mm (in practice to 1e-9 m).
//! Skipped, with a message, without `.venv` + h5py + ouster-sdk (`scripts/setup-ouster`).

mod common;

use pi3det_data::{Dataset, Platform};
use pi3det_sequence::{Sequence, SequenceDataset, SequenceOptions};

#[test]
fn points_match_the_ouster_sdk() {
    let Some(py) = common::python() else { return };
    let dir = tempfile::tempdir().unwrap();
    common::make_sequences(&py, dir.path(), None);
    let seqs = pi3det_sequence::find_sequences(&dir.path().join("processed"));
    assert_eq!(seqs.len(), 3, "{seqs:?}");
    let mut checked = Vec::new();
    for s in &seqs {
        let seq = Sequence::open(s, SequenceOptions::default()).unwrap();
        // The release's layout: each row a packet and ouster-ros' pad byte, which the SDK is
        // not given (the oracle feeds it row[:packet size]).
        assert_eq!(seq.row_pad_bytes(), 1, "{}", seq.name);
        let oracle = common::oracle(&py, &seq.data_path, dir.path());
        assert_eq!(oracle.len(), seq.len());
        let mut worst = 0.0f64;
        for (k, want) in oracle.iter().enumerate() {
            let got = seq.sweep_points(k).unwrap();
            assert_eq!(got.len(), want.len(), "{} sweep {k}: point count", seq.name);
            for (i, (g, w)) in got.iter().zip(want).enumerate() {
                let d = (0..3).map(|c| (g.xyz[c] - w.xyz[c]).abs()).fold(0.0, f64::max);
                worst = worst.max(d);
                assert!(d <= 1e-3, "{} sweep {k} point {i}: {:?} vs SDK {:?}", seq.name, g.xyz, w.xyz);
                assert_eq!(f64::from(g.reflectivity), w.reflectivity, "{} sweep {k} point {i}", seq.name);
                assert_eq!(g.timestamp_ns, w.timestamp_ns, "{} sweep {k} point {i}", seq.name);
                assert_eq!(u32::from(g.beam), w.beam, "{} sweep {k} point {i}", seq.name);
            }
            // The frame's float32 points are the same, with intensity = reflectivity / 255.
            let frame = seq.load(k).unwrap();
            assert_eq!(frame.points.len(), want.len());
            for (p, w) in frame.points.iter().zip(want) {
                assert!((0..3).all(|c| (f64::from(p[c]) - w.xyz[c]).abs() <= 1e-3));
                assert_eq!(p[3], (w.reflectivity.min(255.0) / 255.0) as f32);
            }
        }
        eprintln!(
            "{}: {:?} {}x{} ({} beams), {} sweeps, worst |Δ| {worst:.2e} m",
            seq.name,
            seq.metadata.profile,
            seq.metadata.columns_per_frame,
            seq.metadata.fps.unwrap_or(0),
            seq.metadata.pixels_per_column,
            seq.len()
        );
        checked.push((seq.platform, seq.metadata.pixels_per_column, seq.metadata.profile));
    }
    // The three metadata variants were all exercised.
    assert!(checked.iter().any(|c| c.0 == Platform::Vehicle && c.1 == 64));
    assert!(checked.iter().any(|c| c.0 == Platform::Drone && c.1 == 32));
    assert!(checked.iter().any(|c| c.0 == Platform::Quadruped));

    // The tree as one dataset: frames, platforms, sequences, timestamps, poses, labels.
    let ds = SequenceDataset::open(&dir.path().join("processed"), SequenceOptions::default()).unwrap();
    assert_eq!(ds.len(), 9);
    let info = ds.info(1).unwrap();
    assert_eq!(info.platform, Platform::Vehicle);
    assert_eq!(info.sequence.as_deref(), Some("car_urban_day_penno_small_loop"));
    assert_eq!(info.id, "car_urban_day_penno_small_loop_00001");
    assert!((info.timestamp_s.unwrap() - 1_650_000_000.1).abs() < 1e-6);
    // world_from_lidar is the inverse of the stored Ln_T_L0 (the fixture's translation 1.5·k).
    let t = info.world_from_lidar.unwrap().inverse().translation;
    assert!((t.x - 1.5).abs() < 1e-12 && (t.y - 0.2).abs() < 1e-12);
    let names: Vec<&str> = info.objects.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names, ["Vehicle", "Pedestrian", "Pedestrian", "ignored_Vehicle"]);
    assert_eq!(info.objects[0].box3d.x, 11.0);
    assert_eq!(info.objects[0].score, Some(0.93f32 as f64));
    assert_eq!(ds.info(3).unwrap().platform, Platform::Drone);
    assert_eq!(ds.info(6).unwrap().platform, Platform::Quadruped);
}
