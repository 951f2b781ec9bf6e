//! Reads the real pickles shipped in the repository's sibling `shared/data/` folder.

use std::path::PathBuf;

use pi3det_data::pickle::{self, ArrayData, Value};

fn shared(rel: &str) -> PathBuf {
    let path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/")).join(rel);
    assert!(
        path.is_file(),
        "test data {} is missing: these tests need the `shared/` folder next to the repository root",
        path.display()
    );
    path
}

fn str_of<'a>(v: &'a Value, key: &str) -> &'a str {
    v.get(key).and_then(Value::as_str).unwrap_or_else(|| panic!("{key} is not a str"))
}

fn assert_close(a: f64, b: f64) {
    assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{a} != {b}");
}

#[test]
fn pi3det_infos() {
    let infos = pickle::from_path(shared("pi3det_sample/pi3det_infos_train.pkl")).unwrap();
    let frames = infos.as_list().expect("a list of frames");
    assert_eq!(frames.len(), 6);
    let ids: Vec<&str> = frames.iter().map(|f| str_of(f, "frame_id")).collect();
    assert_eq!(ids, ["0000000", "0000001", "0000002", "0000003", "0000004", "0000005"]);

    // Frame 0: one pedestrian.
    let f0 = &frames[0];
    assert_eq!(str_of(f0, "platform"), "vehicle");
    assert_eq!(str_of(f0, "image_path"), "training/image/0000000.jpg");
    assert_eq!(str_of(f0, "point_clout_path"), "training/point_cloud/0000000.bin");
    let annos = f0.get("annos").unwrap();
    let names = annos.get("gt_names").and_then(Value::as_array).unwrap();
    assert!(matches!(names.data, ArrayData::Str(_)));
    assert_eq!(names.to_strings().unwrap(), ["Pedestrian"]);
    let boxes = annos.get("gt_boxes_lidar").and_then(Value::as_array).unwrap();
    assert_eq!(boxes.shape(), &[1, 7]);
    assert_eq!(boxes.dtype_name(), "float32");
    let expected = [8.731382f32, -1.8559175, -0.6546993, 1.2, 0.48, 1.89, -1.5807964];
    assert_eq!(boxes.to_f32_vec().unwrap(), expected);
    let calib = f0.get("calib").unwrap();
    let intrinsics = calib.get("I").and_then(Value::as_array).unwrap();
    assert_eq!(intrinsics.shape(), &[3, 3]);
    assert_eq!(intrinsics.to_f64_vec().unwrap(), [707.0493, 0.0, 604.0814, 0.0, 707.0493, 180.5066, 0.0, 0.0, 1.0]);
    let d = calib.get("D").and_then(Value::as_array).unwrap();
    assert_eq!(d.shape(), &[5]);
    assert_eq!(d.to_f64_vec().unwrap(), [0.0; 5]);

    // Frame 1 (KITTI 000001): a Truck, a Car and a Cyclist.
    let f1 = &frames[1];
    let annos = f1.get("annos").unwrap();
    let names = annos.get("gt_names").and_then(Value::as_array).unwrap();
    assert_eq!(names.dtype_name(), "str");
    assert_eq!(names.to_strings().unwrap(), ["Truck", "Car", "Cyclist"]);
    let rows = annos.get("gt_boxes_lidar").and_then(Value::as_array).unwrap().to_f64_rows().unwrap();
    assert_eq!(rows.len(), 3);
    assert!(rows.iter().all(|r| r.len() == 7));
    assert_close(rows[0][0], 69.724792);
    assert_close(rows[0][3], 12.34); // the truck is 12.34 m long
    assert_close(rows[2][5], 1.86);
    let e = f1.get("calib").and_then(|c| c.get("E")).and_then(Value::as_array).unwrap();
    assert_eq!(e.shape(), &[4, 4]);
    assert_eq!(e.dtype_name(), "float64");
    let e = e.to_f64_rows().unwrap();
    assert_eq!(e[3], [0.0, 0.0, 0.0, 1.0]);
    assert_close(e[0][0], 0.00023477369814709992);
    assert_close(e[2][3], -0.2721327964058732);

    // The box counts of all frames.
    let counts: Vec<usize> = frames
        .iter()
        .map(|f| {
            let annos = f.get("annos").unwrap();
            let n = annos.get("gt_names").and_then(Value::as_array).unwrap().len();
            let boxes = annos.get("gt_boxes_lidar").and_then(Value::as_array).unwrap();
            assert_eq!(boxes.shape(), &[n, 7]);
            n
        })
        .collect();
    assert_eq!(counts, [1, 3, 2, 1, 2, 1]);
}

#[test]
fn pi3det_infos_round_trip() {
    let infos = pickle::from_path(shared("pi3det_sample/pi3det_infos_train.pkl")).unwrap();
    let bytes = pickle::to_vec(&infos).unwrap();
    assert_eq!(pickle::from_slice(&bytes).unwrap(), infos);
}

#[test]
fn nuscenes_info() {
    let info = pickle::from_path(shared("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl")).unwrap();
    let meta = info.get("metainfo").unwrap();
    assert_eq!(str_of(meta, "dataset"), "nuscenes");
    assert_eq!(str_of(meta, "version"), "v1.0-mini");
    let categories = meta.get("categories").and_then(Value::as_dict).unwrap();
    assert_eq!(categories.len(), 10);
    assert_eq!(meta.get("categories").unwrap().get("pedestrian"), Some(&Value::Int(7)));

    let samples = info.get("data_list").and_then(Value::as_list).unwrap();
    assert_eq!(samples.len(), 1);
    let sample = &samples[0];
    assert_eq!(str_of(sample, "token"), "ca9a282c9e77460f8360f564131a8af5");
    assert_eq!(sample.get("timestamp").and_then(Value::as_f64), Some(1532402927.647951));
    let lidar = sample.get("lidar_points").unwrap();
    assert_eq!(lidar.get("num_pts_feats").and_then(Value::as_i64), Some(5));
    assert_eq!(str_of(lidar, "lidar_path"), "n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin");
    let ego = sample.get("ego2global").and_then(Value::as_list).unwrap();
    assert_eq!(ego.len(), 4);
    let last: Vec<f64> = ego[3].as_list().unwrap().iter().filter_map(Value::as_f64).collect();
    assert_eq!(last, [0.0, 0.0, 0.0, 1.0]);

    let instances = sample.get("instances").and_then(Value::as_list).unwrap();
    assert_eq!(instances.len(), 69);
    let mut total_pts = 0;
    for inst in instances {
        let bbox = inst.get("bbox_3d").and_then(Value::as_list).unwrap();
        assert_eq!(bbox.len(), 7);
        assert!(bbox.iter().all(|x| x.as_f64().is_some()));
        assert!(inst.get("bbox_label_3d").and_then(Value::as_i64).is_some());
        // numpy int64 / bool scalars decode to plain values.
        total_pts += inst.get("num_lidar_pts").and_then(Value::as_i64).unwrap();
        assert!(matches!(inst.get("bbox_3d_isvalid"), Some(Value::Bool(_))));
    }
    assert_eq!(total_pts, 1009);
    let third = &instances[2];
    assert_eq!(third.get("bbox_label_3d"), Some(&Value::Int(0)));
    assert_eq!(third.get("num_lidar_pts"), Some(&Value::Int(5)));
    assert_eq!(third.get("bbox_3d_isvalid"), Some(&Value::Bool(true)));
    let bbox: Vec<f64> =
        third.get("bbox_3d").and_then(Value::as_list).unwrap().iter().filter_map(Value::as_f64).collect();
    assert_eq!(bbox[3..6], [4.633, 2.011, 1.573]);
    let cars = instances.iter().filter(|i| i.get("bbox_label_3d") == Some(&Value::Int(0))).count();
    assert_eq!(cars, 8);

    let cams = sample.get("cam_instances").and_then(Value::as_dict).unwrap();
    assert_eq!(cams.len(), 6);
    let front = sample.get("cam_instances").unwrap().get("CAM_FRONT").unwrap();
    assert_eq!(front.as_list().unwrap().len(), 47);
    // np.float64 scalars inside a list of floats.
    let bbox2d = front.as_list().unwrap()[0].get("bbox").and_then(Value::as_list).unwrap();
    assert_eq!(bbox2d[0], Value::Float(1206.5693751819117));
}

#[test]
fn missing_file_error_names_the_path() {
    let err = pickle::from_path("/nonexistent/dir/infos.pkl").unwrap_err();
    assert!(err.to_string().contains("/nonexistent/dir/infos.pkl"), "{err}");
}
