//! A loopback replayer sends a faulty packet stream (loss, reordering, duplicates, truncated and
//! garbage datagrams, a frame-id wrap, a sensor restart) to the UDP source, which emits a sweep
//! per sweep that meets the coverage rule, with the points the sequence decoder gives.

use std::net::SocketAddr;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

use pi3det_live::replay::{self, Faults, ReplayPlan};
use pi3det_live::source::ouster_udp::{read_metadata, UdpOptions, UdpSource};
use pi3det_live::{Flow, Source};
use pi3det_sequence::dataset::sweep_points_cloud;
use pi3det_sequence::ouster::{PacketFormat, Sweep, XyzLut};
use pi3det_sequence::synth::{metadata_json, SynthSpec};

fn spec() -> SynthSpec {
    SynthSpec { columns: 512, ..SynthSpec::os1_64("t", 1) }
}

fn source(dir: &std::path::Path) -> (UdpSource, SocketAddr, std::path::PathBuf) {
    let md = dir.join("meta.json");
    std::fs::write(&md, metadata_json(&spec())).unwrap();
    let mut o = UdpOptions::new("127.0.0.1:0".parse().unwrap(), md.clone());
    o.timeout_s = Some(0.6);
    let src = UdpSource::open(&o).unwrap();
    let addr = src.local_addr().unwrap();
    (src, addr, md)
}

fn run(
    mut src: UdpSource,
    sweeps: Vec<Vec<Vec<u8>>>,
    addr: SocketAddr,
) -> (Vec<pi3det_live::LiveFrame>, pi3det_live::SourceReport) {
    let got = Arc::new(Mutex::new(Vec::new()));
    let sink = got.clone();
    let receiver = std::thread::spawn(move || {
        src.run(
            &mut |f| {
                sink.lock().unwrap().push(f);
                Flow::Continue
            },
            &AtomicBool::new(false),
        )
        .unwrap()
    });
    std::thread::sleep(std::time::Duration::from_millis(50));
    // 5 Hz: a slow stream, so a loaded test machine does not overflow the socket buffer.
    replay::send(&sweeps, addr, 5.0).unwrap();
    let report = receiver.join().unwrap();
    let frames = std::mem::take(&mut *got.lock().unwrap());
    (frames, report)
}

#[test]
fn clean_stream_gives_every_sweep_with_the_decoders_points() {
    let dir = tempfile::tempdir().unwrap();
    let (src, addr, md) = source(dir.path());
    let plan = ReplayPlan { sweeps: 5, first_frame_id: 65533, restart_at: None, faults: Faults::default(), seed: 3 };
    let sweeps = replay::datagrams(&spec(), &plan);
    let (frames, report) = run(src, sweeps.clone(), addr);
    assert_eq!(frames.len(), 5, "{report}");
    assert_eq!(report.get("complete"), 5);
    assert_eq!(report.get("wraps"), 1);
    let md = read_metadata(&md).unwrap();
    let (format, lut) = (PacketFormat::new(&md), XyzLut::new(&md));
    for (f, packets) in frames.iter().zip(&sweeps) {
        let mut sweep = Sweep::default();
        format.decode(&packets.concat(), &mut sweep);
        let expected = sweep_points_cloud(&lut, &sweep).unwrap();
        assert!(!expected.is_empty());
        assert_eq!(f.frame.points, expected);
    }
}

#[test]
fn faulty_stream_is_counted_and_never_fatal() {
    let dir = tempfile::tempdir().unwrap();
    let (src, addr, _) = source(dir.path());
    let faults = Faults { loss: 0.05, reorder: 0.05, duplicate: 0.05, truncate: 0.02, garbage: 0.05 };
    let plan = ReplayPlan { sweeps: 12, first_frame_id: 65530, restart_at: Some(8), faults, seed: 11 };
    let sweeps = replay::datagrams(&spec(), &plan);
    let (frames, report) = run(src, sweeps, addr);
    // With 5 % loss (+2 % truncated) nearly every sweep keeps ≥ 75 % of its 32 packets.
    assert!(frames.len() >= 10 && frames.len() <= 12, "{} sweeps: {report}", frames.len());
    for key in ["duplicate", "garbage", "partial"] {
        assert!(report.get(key) > 0, "{key}: {report}");
    }
    assert_eq!(report.get("wraps"), 1, "{report}");
    assert_eq!(report.get("restarts"), 1, "{report}");
    assert_eq!(report.sweeps, frames.len() as u64);
    assert!(frames.iter().all(|f| !f.frame.points.is_empty()));
}

#[test]
fn a_metadata_file_that_does_not_match_the_packets_is_reported() {
    // Packets of a 512-column sensor, metadata of a 1024-column one: every datagram has the
    // wrong size for the layout, so the run ends with all of them counted as garbage.
    let dir = tempfile::tempdir().unwrap();
    let md = dir.path().join("meta.json");
    let other = SynthSpec { beams: 32, ..spec() };
    std::fs::write(&md, metadata_json(&other)).unwrap();
    let mut o = UdpOptions::new("127.0.0.1:0".parse().unwrap(), md);
    o.timeout_s = Some(0.4);
    let src = UdpSource::open(&o).unwrap();
    let addr = src.local_addr().unwrap();
    let plan = ReplayPlan { sweeps: 2, first_frame_id: 0, restart_at: None, faults: Faults::default(), seed: 1 };
    let (frames, report) = run(src, replay::datagrams(&spec(), &plan), addr);
    assert!(frames.is_empty());
    assert_eq!(report.get("garbage"), report.get("packets"));
    assert!(report.get("packets") > 0);
}

#[test]
fn missing_or_broken_metadata_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let o = UdpOptions::new("127.0.0.1:0".parse().unwrap(), dir.path().join("nope.json"));
    let e = UdpSource::open(&o).err().expect("error").to_string();
    assert!(e.contains("nope.json"), "{e}");
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, "{\"lidar_data_format\": 3}").unwrap();
    let e = UdpSource::open(&UdpOptions::new("127.0.0.1:0".parse().unwrap(), bad)).err().expect("error").to_string();
    assert!(e.contains("bad.json"), "{e}");
}

#[test]
fn a_point_cloud_encoded_as_packets_decodes_to_its_points() {
    use pi3det_data::PointCloud;
    let s = SynthSpec::os1_64("t", 1);
    let md =
        pi3det_sequence::ouster::SensorMetadata::parse(std::path::Path::new("m.json"), &metadata_json(&s)).unwrap();
    let (format, lut) = (PacketFormat::new(&md), XyzLut::new(&md));
    // Points exactly on returns of distinct pixels, plus one nobody sees (straight up).
    let mut pts = Vec::new();
    for k in 0..2000usize {
        let (u, v, r) = (k % 64, (k / 64) * 31 % 1024, 2000 + 17 * k as u32);
        let p = lut.xyz(u, v, r);
        pts.push([p[0] as f32, p[1] as f32, p[2] as f32, (k % 256) as f32 / 255.0]);
    }
    pts.push([0.0, 0.0, 30.0, 0.5]);
    let cloud = PointCloud::from_xyzi(&pts);
    let (mut packets, encoded) = replay::encode_cloud(&s, &lut, &cloud, 9, 1_000);
    assert_eq!(encoded, 2000);
    replay::relabel(&format, &mut packets, 42, 5_000_000_000);
    assert_eq!(format.packet_ids(&packets[..format.packet_bytes()]), Some((42, 0, 5_000_000_000)));
    let mut sweep = Sweep::default();
    format.decode(&packets, &mut sweep);
    let back = sweep_points_cloud(&lut, &sweep).unwrap();
    assert_eq!(back.len(), 2000);
    let mut a: Vec<[i64; 4]> = cloud.iter().take(2000).map(key).collect();
    let mut b: Vec<[i64; 4]> = back.iter().map(key).collect();
    a.sort();
    b.sort();
    // float32 input, 1 mm range steps: the same points to a few millimetres.
    for (p, q) in a.iter().zip(&b) {
        for c in 0..3 {
            assert!((p[c] - q[c]).abs() <= 3, "{p:?} vs {q:?}");
        }
        assert_eq!(p[3], q[3]);
    }
}

fn key(p: &[f32]) -> [i64; 4] {
    [(p[0] * 1000.0) as i64, (p[1] * 1000.0) as i64, (p[2] * 1000.0) as i64, (p[3] * 255.0).round() as i64]
}

/// Recorded sweeps of the sequence release (rows with ouster-ros' pad byte) replayed over UDP:
/// the source gets exact-size datagrams and gives the frames the sequence reader gives.
#[test]
fn release_rows_replay_as_the_sensor_sent_them() {
    use pi3det_sequence::synth::write_sequence;
    use pi3det_sequence::{Sequence, SequenceOptions};
    let dir = tempfile::tempdir().unwrap();
    let spec = SynthSpec { frames: 3, ..spec() };
    let seq = Sequence::open(&write_sequence(dir.path(), &spec).unwrap(), SequenceOptions::default()).unwrap();
    assert_eq!(seq.row_pad_bytes(), 1);
    let sweeps = replay::sequence_datagrams(&seq, 0..seq.len()).unwrap();
    assert!(sweeps.iter().flatten().all(|d| d.len() == seq.format.packet_bytes()));
    let (src, addr, _) = source(dir.path());
    let (frames, report) = run(src, sweeps, addr);
    assert_eq!(frames.len(), 3, "{report}");
    assert_eq!(report.get("garbage"), 0, "{report}");
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(f.frame.points, seq.load(k).unwrap().points, "sweep {k}");
    }
}
