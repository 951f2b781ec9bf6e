//! The Pi3DET-layout writer: round trip through our reader, never overwrites unasked, and Python's
//! `pickle` + numpy load what it writes into the arrays the public code expects.

mod common;

use std::path::Path;
use std::process::Command;

use pi3det_data::pi3det::Pi3detWriter;
use pi3det_data::{open, Frame, FrameInfo, Object, Platform, PointCloud};
use pi3det_geometry::{Box3d, Pose, PoseExt};

fn frame(id: &str, seq: &str) -> Frame {
    let mut info = FrameInfo::new(id, Default::default());
    info.platform = Platform::Drone;
    info.sequence = Some(seq.into());
    info.timestamp_s = Some(12.5);
    info.world_from_lidar = Some(Pose::from_xyz_rpy([1.0, 2.0, 10.0], 0.1, -0.2, 0.3));
    let mut car = Object::new("Car", Box3d::new(10.0, 1.0, -9.0, 4.2, 1.9, 1.6, 0.25));
    car.num_points = Some(3);
    info.objects = vec![car, Object::new("Pedestrian", Box3d::new(5.0, -2.0, -9.5, 0.6, 0.7, 1.75, -1.0))];
    let points = PointCloud::from_xyzi(&[
        [10.0, 1.0, -9.0, 0.5],
        [10.5, 1.2, -9.1, 0.25],
        [9.0, 0.5, -8.5, 1.0],
        [0.0, 0.0, 0.0, 0.0],
    ]);
    Frame { info, points }
}

fn write_dataset(root: &Path, overwrite: bool) -> Result<(), pi3det_data::DataError> {
    let mut w = Pi3detWriter::create(root, "train", overwrite)?;
    w.write_frame(&frame("0000000", "seq_a"))?;
    w.write_frame(&frame("0000001", "seq_a"))?;
    w.finish()?;
    Ok(())
}

#[test]
fn round_trip_through_reader() {
    let dir = tempfile::tempdir().unwrap();
    write_dataset(dir.path(), false).unwrap();
    let ds = open(dir.path()).unwrap();
    assert_eq!(ds.len(), 2);
    let back = ds.load(1).unwrap();
    let orig = frame("0000001", "seq_a");
    assert_eq!(back.info.id, "0000001");
    assert_eq!(back.info.platform, Platform::Drone);
    assert_eq!(back.info.sequence.as_deref(), Some("seq_a"));
    assert_eq!(back.info.timestamp_s, Some(12.5));
    assert_eq!(back.points, orig.points);
    let (p, q) = (back.info.world_from_lidar.unwrap(), orig.info.world_from_lidar.unwrap());
    assert!((p.to_homogeneous() - q.to_homogeneous()).abs().max() < 1e-12);
    for (a, b) in back.info.objects.iter().zip(&orig.info.objects) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.num_points, b.num_points);
        for (x, y) in a.box3d.to_array().iter().zip(b.box3d.to_array()) {
            assert!((x - y).abs() < 1e-5);
        }
    }
}

#[test]
fn refuses_to_overwrite_unless_asked() {
    let dir = tempfile::tempdir().unwrap();
    write_dataset(dir.path(), false).unwrap();
    let e = write_dataset(dir.path(), false).err().unwrap().to_string();
    assert!(e.contains("already exists"), "{e}");
    write_dataset(dir.path(), true).unwrap();
}

/// Python with numpy: `PI3DET_PYTHON`, the repo's `.venv`, or `python3`.
fn python_with_numpy() -> Option<String> {
    let venv = concat!(env!("CARGO_MANIFEST_DIR"), "/../../.venv/bin/python");
    let candidates = [std::env::var("PI3DET_PYTHON").ok(), Some(venv.to_string()), Some("python3".into())];
    candidates
        .into_iter()
        .flatten()
        .find(|py| Command::new(py).args(["-c", "import numpy"]).output().map(|o| o.status.success()).unwrap_or(false))
}

#[test]
fn python_pickle_loads_the_info_file() {
    let Some(py) = python_with_numpy() else {
        eprintln!("note: no python3 with numpy (run scripts/setup-python); skipping the Python load check");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    write_dataset(dir.path(), false).unwrap();
    let script = r#"
import pickle, sys, numpy as np
infos = pickle.load(open(sys.argv[1] + '/pi3det_infos_train.pkl', 'rb'))
assert isinstance(infos, list) and len(infos) == 2
i = infos[1]
assert i['frame_id'] == '0000001' and i['platform'] == 'drone' and i['sequence'] == 'seq_a'
assert i['point_clout_path'] == 'training/point_cloud/0000001.bin'
a = i['annos']
assert a['gt_names'].dtype.kind == 'U' and list(a['gt_names']) == ['Car', 'Pedestrian']
assert a['gt_boxes_lidar'].dtype == np.float32 and a['gt_boxes_lidar'].shape == (2, 7)
assert abs(a['gt_boxes_lidar'][0, 3] - 4.2) < 1e-6
assert list(a['num_points_in_gt']) == [3, -1]
assert i['pose'].shape == (4, 4) and i['pose'].dtype == np.float64 and i['pose'][3, 3] == 1.0
pts = np.fromfile(sys.argv[1] + '/' + i['point_clout_path'], dtype=np.float32).reshape(-1, 4)
assert pts.shape == (4, 4) and pts[1, 3] == 0.25
print('ok')
"#;
    let out = Command::new(&py).args(["-c", script, dir.path().to_str().unwrap()]).output().unwrap();
    assert!(out.status.success(), "python failed: {}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), "ok");
}

#[test]
fn kitti_result_files_round_trip_through_calib() {
    use pi3det_data::kitti::{read_labels, write_result_file};
    use pi3det_data::Calib;
    let kitti = open(&common::shared_data("kitti/training")).unwrap();
    let info = kitti.info(1).unwrap();
    let Some(Calib::Kitti(calib)) = &info.calib else { panic!("KITTI frames carry a calib") };
    let mut dets = info.objects.clone();
    for (k, d) in dets.iter_mut().enumerate() {
        d.score = Some(0.9 - 0.1 * k as f64);
    }
    let dir = tempfile::tempdir().unwrap();
    write_result_file(dir.path(), &info.id, &dets, Some(calib), false).unwrap();
    assert!(write_result_file(dir.path(), &info.id, &dets, Some(calib), false).is_err());
    let back = read_labels(&dir.path().join("000001.txt")).unwrap();
    assert_eq!(back.len(), 3);
    for (l, d) in back.iter().zip(&dets) {
        assert_eq!(l.name, d.name);
        assert_eq!(l.score, d.score);
        let b = l.to_object(calib).box3d;
        // 4 decimals in the file: millimetre agreement.
        for (x, y) in b.to_array().iter().zip(d.box3d.to_array()) {
            assert!((x - y).abs() < 2e-3, "{b:?} vs {:?}", d.box3d);
        }
    }
}

/// A corrected label set beside the original: same point files, none written, and the folder
/// still opens as the original frames only.
#[test]
fn label_set_beside_the_original_points_at_the_same_files() {
    let dir = tempfile::tempdir().unwrap();
    write_dataset(dir.path(), false).unwrap();
    let original = std::fs::read(dir.path().join("pi3det_infos_train.pkl")).unwrap();
    let ds = open(dir.path()).unwrap();
    let mut infos: Vec<FrameInfo> = (0..ds.len()).map(|i| ds.info(i).unwrap()).collect();
    infos[1].objects.truncate(1);
    infos[1].objects[0].box3d.x += 1.0;
    let edit = dir.path().join("pi3det_infos_train.edit-001.pkl");
    pi3det_data::pi3det::write_infos(&edit, &infos, false).unwrap();
    assert!(matches!(
        pi3det_data::pi3det::write_infos(&edit, &infos, false),
        Err(pi3det_data::DataError::Exists { .. })
    ));
    assert_eq!(std::fs::read(dir.path().join("pi3det_infos_train.pkl")).unwrap(), original);
    assert_eq!(open(dir.path()).unwrap().len(), 2, "the label set is not read as another split");
    let e = open(&edit).unwrap();
    assert_eq!(e.len(), 2);
    assert_eq!(e.info(1).unwrap().points_path, ds.info(1).unwrap().points_path);
    assert_eq!(e.info(1).unwrap().objects.len(), 1);
    assert_eq!(e.info(1).unwrap().objects[0].box3d.x, 11.0);
    let (a, b) = (e.info(0).unwrap(), ds.info(0).unwrap());
    assert_eq!((&a.id, &a.objects, &a.sequence, &a.points_path), (&b.id, &b.objects, &b.sequence, &b.points_path));
    assert_eq!(e.load(0).unwrap().points, ds.load(0).unwrap().points);
    // Points outside the info file's folder are referenced by absolute path.
    let other = tempfile::tempdir().unwrap();
    let elsewhere = other.path().join("pi3det_infos_val.pkl");
    pi3det_data::pi3det::write_infos(&elsewhere, &infos, false).unwrap();
    assert_eq!(open(&elsewhere).unwrap().load(1).unwrap().points, ds.load(1).unwrap().points);
}
