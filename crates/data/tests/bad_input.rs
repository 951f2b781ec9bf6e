//! Bad input gets a clear error naming the file and the problem, never a panic.

use std::fs;

use pi3det_data::kitti::{read_calib, read_labels};
use pi3det_data::{open, read_bin, DataError};

fn write(dir: &std::path::Path, rel: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(rel);
    fs::create_dir_all(p.parent().unwrap()).unwrap();
    fs::write(&p, bytes).unwrap();
    p
}

fn floats(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

#[test]
fn truncated_bin_names_file_and_size() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "a.bin", &floats(&[1.0, 2.0, 3.0, 0.5, 9.0])[..18]);
    let e = read_bin(&p, &["x", "y", "z", "intensity"]).err().unwrap().to_string();
    assert!(e.contains("a.bin") && e.contains("not a multiple of 16"), "{e}");
}

#[test]
fn nan_points_are_dropped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let pts = [1.0, 2.0, 3.0, 0.5, f32::NAN, 0.0, 0.0, 0.1, 4.0, f32::INFINITY, 1.0, 0.2, 7.0, 8.0, 9.0, f32::NAN];
    let p = write(dir.path(), "b.bin", &floats(&pts));
    let r = read_bin(&p, &["x", "y", "z", "intensity"]).unwrap();
    assert_eq!(r.dropped_non_finite, 2);
    assert_eq!(r.cloud.len(), 2);
    // A NaN intensity is not a NaN coordinate: the point stays.
    assert!(r.cloud.point(1)[3].is_nan());
}

#[test]
fn missing_file_and_folder() {
    let e = read_bin(std::path::Path::new("/nonexistent/x.bin"), &["x", "y", "z"]).err().unwrap().to_string();
    assert!(e.contains("/nonexistent/x.bin"), "{e}");
    let e = open(std::path::Path::new("/nonexistent/dataset")).err().unwrap().to_string();
    assert!(e.contains("/nonexistent/dataset") && e.contains("no such"), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let e = open(dir.path()).err().unwrap();
    assert!(matches!(e, DataError::UnknownFormat { .. }), "{e}");
}

#[test]
fn malformed_label_line_gives_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "label_2/000000.txt",
        b"Car 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57\n\nCar 0.00 0 oops\n",
    );
    let e = read_labels(&p).err().unwrap().to_string();
    assert!(e.contains("000000.txt:3:") && e.contains("15 or 16"), "{e}");
}

#[test]
fn unknown_class_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "l.txt",
        b"Hovercraft 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57\n",
    );
    assert_eq!(read_labels(&p).unwrap()[0].name, "Hovercraft");
}

#[test]
fn calib_missing_key_and_bad_values() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "c.txt", b"P2: 1 2 3\n");
    let e = read_calib(&p).err().unwrap().to_string();
    assert!(e.contains("c.txt") && e.contains("'P2' needs 12"), "{e}");
    let p = write(dir.path(), "d.txt", b"P0: 1\n");
    let e = read_calib(&p).err().unwrap().to_string();
    assert!(e.contains("missing 'P2'"), "{e}");
}

#[test]
fn kitti_frame_with_missing_calib_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "velodyne/000000.bin", &floats(&[1.0, 2.0, 3.0, 0.5]));
    let ds = open(dir.path()).unwrap();
    let e = ds.info(0).err().unwrap().to_string();
    assert!(e.contains("calib/000000.txt"), "{e}");
}

#[test]
fn pi3det_info_with_bad_fields() {
    use pi3det_data::pickle::{to_vec, NdArray, Value};
    let dir = tempfile::tempdir().unwrap();
    let info = |boxes: NdArray, names: Vec<String>| {
        Value::List(vec![Value::dict([
            ("frame_id", Value::Str("0000000".into())),
            (
                "annos",
                Value::dict([
                    ("gt_names", Value::Array(NdArray::from_vec(names))),
                    ("gt_boxes_lidar", Value::Array(boxes)),
                ]),
            ),
        ])])
    };
    let two = NdArray::new(vec![2, 7], vec![0.0f32; 14]).unwrap();
    write(dir.path(), "pi3det_infos_train.pkl", &to_vec(&info(two, vec!["Car".into()])).unwrap());
    let e = open(dir.path()).err().unwrap().to_string();
    assert!(
        e.contains("pi3det_infos_train.pkl") && e.contains("frame 0000000") && e.contains("1 gt_names but 2"),
        "{e}"
    );
    let nan = NdArray::new(vec![1, 7], vec![f32::NAN, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0]).unwrap();
    write(dir.path(), "pi3det_infos_train.pkl", &to_vec(&info(nan, vec!["Car".into()])).unwrap());
    let e = open(dir.path()).err().unwrap().to_string();
    assert!(e.contains("box 0") && e.contains("non-finite"), "{e}");
    let narrow = NdArray::new(vec![1, 6], vec![0.0f32; 6]).unwrap();
    write(dir.path(), "pi3det_infos_train.pkl", &to_vec(&info(narrow, vec!["Car".into()])).unwrap());
    let e = open(dir.path()).err().unwrap().to_string();
    assert!(e.contains("at least 7"), "{e}");
    write(dir.path(), "pi3det_infos_train.pkl", b"\x80\x04garbage");
    let e = open(dir.path()).err().unwrap().to_string();
    assert!(e.contains("pi3det_infos_train.pkl"), "{e}");
}

#[test]
fn empty_frames_written_by_openpcdet_are_read() {
    use pi3det_data::pickle::{to_vec, NdArray, Value};
    let dir = tempfile::tempdir().unwrap();
    let info = Value::List(vec![Value::dict([
        ("frame_id", Value::Str("0000000".into())),
        (
            "annos",
            Value::dict([
                ("gt_names", Value::Array(NdArray::from_vec(Vec::<f64>::new()))),
                ("gt_boxes_lidar", Value::Array(NdArray::new(vec![0, 7], Vec::<f32>::new()).unwrap())),
            ]),
        ),
    ])]);
    write(dir.path(), "pi3det_infos_val.pkl", &to_vec(&info).unwrap());
    let ds = open(dir.path()).unwrap();
    assert!(ds.info(0).unwrap().objects.is_empty());
}
