//! Sequences (written in pure Rust, no Python needed) → `convert` → the released layout read back
//! with `pi3det_data::open`: the same float32 points, poses, boxes, sequences and timestamps.

use pi3det_data::{Dataset, Platform};
use pi3det_geometry::PoseExt;
use pi3det_sequence::convert::{to_pi3det_layout, ConvertOptions};
use pi3det_sequence::ouster::UdpProfile;
use pi3det_sequence::synth::{write_sequence, SynthSpec};
use pi3det_sequence::{SequenceDataset, SequenceOptions};

#[test]
fn convert_then_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let processed = dir.path().join("processed");
    write_sequence(&processed.join("Car/urban_day"), &SynthSpec::os1_64("car_urban_day_a", 3)).unwrap();
    let falcon = SynthSpec {
        beams: 32,
        columns: 512,
        profile: UdpProfile::Rng19Rfl8Sig16Nir16,
        seed: 7,
        ..SynthSpec::os1_64("falcon_outdoor_night_b", 2)
    };
    write_sequence(&processed.join("Falcon/outdoor_night"), &falcon).unwrap();

    let seqs = SequenceDataset::open(&processed, SequenceOptions::default()).unwrap();
    assert_eq!(seqs.len(), 5);
    let out = dir.path().join("layout");
    let report = to_pi3det_layout(&[&seqs], &out, &ConvertOptions::default(), |_, _| {}).unwrap();
    assert_eq!(report.frames, 5);
    assert!(report.info_path.ends_with("pi3det_infos_train.pkl"));
    // Refused a second time, accepted with overwrite.
    let again = to_pi3det_layout(&[&seqs], &out, &ConvertOptions::default(), |_, _| {});
    assert!(again.unwrap_err().to_string().contains("already exists"));
    let opts = ConvertOptions { overwrite: true, ..Default::default() };
    to_pi3det_layout(&[&seqs], &out, &opts, |_, _| {}).unwrap();

    let back = pi3det_data::open(&out).unwrap();
    assert_eq!(back.len(), seqs.len());
    let mut points = 0;
    for i in 0..seqs.len() {
        let a = seqs.load(i).unwrap();
        let b = back.load(i).unwrap();
        assert_eq!(a.info.id, b.info.id);
        assert_eq!(a.info.platform, b.info.platform);
        assert_eq!(a.info.sequence, b.info.sequence);
        assert_eq!(a.info.timestamp_s, b.info.timestamp_s);
        let (pa, pb) = (a.info.world_from_lidar.unwrap(), b.info.world_from_lidar.unwrap());
        let (ma, mb) = (pa.to_matrix_rows(), pb.to_matrix_rows());
        let d = ma.iter().flatten().zip(mb.iter().flatten()).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(d < 1e-12, "pose differs by {d}");
        // Points: the released layout's x, y, z, intensity, bit for bit.
        assert_eq!(a.points.to_xyzi(), b.points);
        points += b.points.len();
        assert_eq!(a.info.objects.len(), b.info.objects.len());
        for (oa, ob) in a.info.objects.iter().zip(&b.info.objects) {
            assert_eq!(oa.name, ob.name);
            // The released layout stores boxes as float32.
            let (ba, bb) = (oa.box3d.to_array(), ob.box3d.to_array());
            assert!(ba.iter().zip(bb).all(|(x, y)| (*x as f32) == (y as f32)), "{ba:?} vs {bb:?}");
        }
    }
    assert!(points > 100_000, "{points} points");
    assert_eq!(back.info(0).unwrap().platform, Platform::Vehicle);
    assert_eq!(back.info(4).unwrap().platform, Platform::Drone);
    let names: Vec<String> = back.info(0).unwrap().objects.iter().map(|o| o.name.clone()).collect();
    assert_eq!(names, ["Vehicle", "Pedestrian", "Pedestrian", "ignored_Vehicle"]);
}

#[test]
fn drone_and_quadruped_boxes_come_back_from_the_levelled_frame() {
    use pi3det_geometry::Pose;
    use pi3det_sequence::labels::{objects, LabelFrame, PseudoBox};
    let b = [PseudoBox { box3d: [10.0, 0.0, -1.0, 4.0, 2.0, 1.5, 0.0], label: 1, score: 0.9 }];
    // Level sensor 20 m above the first frame: drone boxes are in a frame 1.7 m above the
    // ground below it (lifted by 20 − 1.7), quadruped boxes 1.3 m below the sensor's level frame.
    let pose = Pose::from_xyz_rpy([0.0, 0.0, 20.0], 0.0, 0.0, 0.7);
    let d = objects(&b, Platform::Drone, "falcon_x", Some(&pose), LabelFrame::Release).unwrap();
    assert!((d[0].box3d.z - (-1.0 - 18.3)).abs() < 1e-12);
    let q = objects(&b, Platform::Quadruped, "spot_x", Some(&pose), LabelFrame::Release).unwrap();
    assert!((q[0].box3d.z - 0.3).abs() < 1e-12);
    // Pitch is undone: a box straight ahead in the levelled frame is below the pitched-up beam.
    let pitched = Pose::from_xyz_rpy([0.0, 0.0, 0.0], 0.0, 0.1, 0.0);
    let q = objects(&b, Platform::Quadruped, "spot_x", Some(&pitched), LabelFrame::Release).unwrap();
    let want = pitched.rotation.inverse() * nalgebra::Vector3::new(10.0, 0.0, 0.3);
    assert!((q[0].box3d.x - want.x).abs() < 1e-12 && (q[0].box3d.z - want.z).abs() < 1e-12);
    // Vehicle boxes, and the lidar label frame, are taken as stored.
    let v = objects(&b, Platform::Vehicle, "car_x", Some(&pose), LabelFrame::Release).unwrap();
    assert_eq!(v[0].box3d.to_array(), b[0].box3d);
    let l = objects(&b, Platform::Drone, "falcon_x", Some(&pose), LabelFrame::Lidar).unwrap();
    assert_eq!(l[0].box3d.to_array(), b[0].box3d);
    // Without a pose the levelled boxes cannot be placed: an error, not a guess.
    assert!(objects(&b, Platform::Drone, "falcon_x", None, LabelFrame::Release).is_err());
}

/// The release's rows (each packet followed by ouster-ros' pad byte) and exact-size rows of the
/// same packets decode to the same points, frames and packets, in both packet profiles.
#[test]
fn padded_and_unpadded_rows_give_the_same_frames() {
    use pi3det_sequence::ouster::ROS_PACKET_PAD_BYTES;
    use pi3det_sequence::Sequence;
    let dir = tempfile::tempdir().unwrap();
    for profile in [UdpProfile::Legacy, UdpProfile::Rng19Rfl8Sig16Nir16] {
        let base = SynthSpec { columns: 512, profile, ..SynthSpec::os1_64("pad", 2) };
        assert_eq!(base.row_pad_bytes, ROS_PACKET_PAD_BYTES, "the release layout is the default");
        let padded = write_sequence(&dir.path().join(format!("{profile:?}/padded")), &base).unwrap();
        let exact = SynthSpec { row_pad_bytes: 0, ..base.clone() };
        let exact = write_sequence(&dir.path().join(format!("{profile:?}/exact")), &exact).unwrap();
        let (a, b) = (
            Sequence::open(&padded, SequenceOptions::default()).unwrap(),
            Sequence::open(&exact, SequenceOptions::default()).unwrap(),
        );
        assert_eq!((a.row_pad_bytes(), b.row_pad_bytes()), (1, 0));
        let packet = a.format.packet_bytes();
        assert_eq!(a.read_row(0).unwrap().len(), 32 * (packet + 1));
        assert_eq!(b.read_row(0).unwrap().len(), 32 * packet);
        for k in 0..a.len() {
            let (pa, pb) = (a.read_packets(k).unwrap(), b.read_packets(k).unwrap());
            assert_eq!(pa, pb, "{profile:?} sweep {k}: packets");
            assert!(pa.iter().all(|p| p.len() == packet));
            let (fa, fb) = (a.load(k).unwrap(), b.load(k).unwrap());
            assert!(fa.points.len() > 10_000);
            assert_eq!(fa.points, fb.points, "{profile:?} sweep {k}: points");
        }
    }
}
