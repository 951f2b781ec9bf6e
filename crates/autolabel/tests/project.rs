//! The projection check on the shared real frames (KITTI 000001, the nuScenes demo sample, the
//! Pi3DET sample), by hand-computed pixels, and on bad input. Outputs go to temp folders.

use std::path::{Path, PathBuf};

use pi3det_autolabel::project::{
    self, frame_cameras, frame_items, project_frame, view_box, CameraModel, Flag, FrameRange, ProjectOptions, Source,
};
use pi3det_data::{CameraInfo, FrameInfo};
use pi3det_geometry::Box3d;

const SHARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data");
const PYTHON: &str = "/work/main/.venv/bin/python";

/// `../shared/data` beside the repository; as in the data tests, missing data fails loudly.
fn shared(rel: &str) -> PathBuf {
    let p = Path::new(SHARED).join(rel);
    assert!(p.exists(), "real test data missing: {} (expected ../shared/data beside the repo)", p.display());
    p
}

fn nuscenes_pkl() -> PathBuf {
    shared("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl")
}

fn nuscenes_info() -> FrameInfo {
    pi3det_data::open(&nuscenes_pkl()).unwrap().info(0).unwrap()
}

fn close(a: [f64; 2], b: [f64; 2], tol: f64) -> bool {
    (a[0] - b[0]).abs() < tol && (a[1] - b[1]).abs() < tol
}

fn options(data: PathBuf, out: &Path) -> ProjectOptions {
    ProjectOptions { data, out: out.to_path_buf(), ..Default::default() }
}

#[test]
fn kitti_point_matches_rect_to_image_and_hand_values() {
    let path = shared("kitti/training/calib/000001.txt");
    let calib = pi3det_data::kitti::read_calib(&path).unwrap();
    let cam = CameraModel::from_info(&CameraInfo::from_kitti(&calib, None));
    let p = [10.0, 1.0, -1.0];
    let ours = cam.project(p).unwrap();
    let theirs = calib.rect_to_image(calib.lidar_to_rect(p)).unwrap();
    assert!(close(ours, theirs, 1e-6), "{ours:?} vs {theirs:?}");
    // P2 · R0_rect · Tr_velo_to_cam · [10, 1, −1, 1] computed with numpy from the file's numbers.
    assert!(close(ours, [540.52288722, 250.01919714], 1e-6), "{ours:?}");
    // Camera 2 sits 6 cm left of the rectified camera 0; our camera z is P2's third row.
    assert!((cam.to_camera(p).z - 9.71974003559687).abs() < 1e-9);
}

#[test]
fn kitti_frame_is_drawn_on_a_canvas() {
    let data = shared("kitti/training");
    let out = tempfile::tempdir().unwrap();
    let mut opts = options(data, out.path());
    opts.frames = Some("1..2".parse().unwrap());
    let report = project::project(&opts).unwrap();
    assert_eq!(report.frames.len(), 1);
    let f = &report.frames[0];
    assert_eq!(f.frame_id, "000001");
    assert_eq!(f.cameras.len(), 1);
    let c = &f.cameras[0];
    assert_eq!((c.name.as_str(), c.image.as_str(), c.width, c.height), ("image_2", "none, canvas", 1242, 375));
    assert!(c.image_missing.as_deref().unwrap().contains("image_2/000001.png"));
    // Truck, Car, Cyclist: all labelled in this image, so all seen.
    assert_eq!(f.boxes.len(), 3);
    assert!(f.boxes.iter().all(|b| b.cameras == ["image_2"] && b.flag.is_none()), "{:?}", f.boxes);
    let img = image::open(out.path().join(&c.output)).unwrap();
    assert_eq!((img.width(), img.height()), (1242, 375));
    assert!(out.path().join("projection_report.json").exists());
    assert_eq!(report.summary.seen, 3);
    // The projected 3-D boxes cover the labelled 2-D boxes (KITTI's are tight on visible pixels).
    let info = pi3det_data::open(&shared("kitti/training")).unwrap().info(1).unwrap();
    let cam = &frame_cameras(&info)[0];
    for o in &info.objects {
        let r = view_box(cam, &o.box3d).image_bbox(1242, 375).unwrap();
        let l = o.kitti.unwrap().bbox_2d;
        let inter = (r[2].min(l[2]) - r[0].max(l[0])).max(0.0) * (r[3].min(l[3]) - r[1].max(l[1])).max(0.0);
        let union = (r[2] - r[0]) * (r[3] - r[1]) + (l[2] - l[0]) * (l[3] - l[1]) - inter;
        assert!(inter / union > 0.6, "{}: projected {r:?}, label {l:?}", o.name);
    }
}

#[test]
fn nuscenes_cameras_are_read() {
    let info = nuscenes_info();
    let names: Vec<&str> = info.cameras.iter().map(|c| c.name.as_str()).collect();
    for n in ["CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_FRONT_LEFT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_BACK_RIGHT"] {
        assert!(names.contains(&n), "{names:?}");
    }
    assert_eq!(names.len(), 6);
    for c in &info.cameras {
        let p = c.image_path.as_ref().unwrap();
        assert!(p.exists(), "{}", p.display());
        assert!(p.to_string_lossy().contains(&format!("__{}__", c.name)));
    }
    assert_eq!(info.objects.len(), 69);
}

#[test]
fn nuscenes_point_by_hand() {
    let info = nuscenes_info();
    let front = info.cameras.iter().find(|c| c.name == "CAM_FRONT").unwrap();
    let cam = CameraModel::from_info(front);
    // numpy: K = cam2img, E = lidar2cam; K · (E · [1, 10, −0.5, 1])[:3], divided by z.
    let p = [1.0, 10.0, -0.5];
    assert!(close(cam.project(p).unwrap(), [955.08973945, 541.02376124], 1e-6));
    // Behind the ego (LIDAR_TOP's y points forward) CAM_FRONT sees nothing.
    assert_eq!(cam.project([1.0, -10.0, -0.5]), None);
    // The same through Python when the project's venv is there.
    if !Path::new(PYTHON).exists() {
        eprintln!("skipping the numpy cross-check: {PYTHON} not found");
        return;
    }
    let script = format!(
        "import pickle, numpy as np\n\
         s = pickle.load(open({:?}, 'rb'))['data_list'][0]\n\
         for name, c in sorted(s['images'].items()):\n\
         \x20   q = np.array(c['lidar2cam']) @ np.array([-3.0, 4.0, 0.5, 1.0])\n\
         \x20   u = np.array(c['cam2img'])[:3, :3] @ q[:3]\n\
         \x20   print(name, q[2], u[0] / u[2], u[1] / u[2])\n",
        nuscenes_pkl()
    );
    let out = std::process::Command::new(PYTHON).arg("-c").arg(&script).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(text.lines().count(), 6);
    for line in text.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        let cam = CameraModel::from_info(info.cameras.iter().find(|c| c.name == w[0]).unwrap());
        let v: Vec<f64> = w[1..].iter().map(|x| x.parse().unwrap()).collect();
        match cam.project([-3.0, 4.0, 0.5]) {
            Some(px) => assert!(v[0] >= project::NEAR && close(px, [v[1], v[2]], 1e-6), "{line}: {px:?}"),
            None => assert!(v[0] < project::NEAR, "{line}"),
        }
    }
}

#[test]
fn nuscenes_front_boxes_seen_by_cam_front_and_rear_ones_not() {
    let info = nuscenes_info();
    let cams = frame_cameras(&info);
    let front = cams.iter().find(|c| c.name == "CAM_FRONT").unwrap();
    let items = frame_items(&info, &[], None);
    assert_eq!(items.len(), 69);
    let (mut ahead, mut ahead_seen, mut rear) = (0, 0, 0);
    for it in &items {
        let b = it.box3d;
        let seen = view_box(front, &b).in_image(1600, 900);
        // Within ±20° of straight ahead and 5–60 m away.
        if b.y > 5.0 && b.y < 60.0 && b.x.abs() < 0.36 * b.y {
            ahead += 1;
            ahead_seen += usize::from(seen);
        }
        if b.y < -2.0 {
            rear += 1;
            assert!(!seen, "a box behind the ego is in CAM_FRONT: {b:?}");
        }
    }
    assert!(ahead >= 5 && rear >= 5, "{ahead} ahead, {rear} behind");
    assert!(ahead_seen * 10 >= ahead * 9, "{ahead_seen} of {ahead} boxes ahead seen");
}

#[test]
fn nuscenes_demo_draws_six_real_images() {
    let data = nuscenes_pkl();
    let out = tempfile::tempdir().unwrap();
    let report = project::project(&options(data, out.path())).unwrap();
    let f = &report.frames[0];
    assert_eq!(f.cameras.len(), 6);
    for c in &f.cameras {
        assert!(c.image_missing.is_none() && c.image.ends_with(".jpg"), "{c:?}");
        assert_eq!((c.width, c.height), (1600, 900));
        let img = image::open(out.path().join(&c.output)).unwrap();
        assert_eq!((img.width(), img.height()), (1600, 900));
    }
    let s = &report.summary;
    assert_eq!((s.boxes_gt, s.images_written), (69, 6));
    assert_eq!(s.seen + s.outside_all_images + s.behind_all_cameras, 69);
    // Six cameras cover 360°: nothing is behind all of them.
    assert_eq!(s.behind_all_cameras, 0);
    assert!(s.seen >= 55, "{s:?}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("projection_report.json")).unwrap()).unwrap();
    assert_eq!(json["frames"][0]["boxes"].as_array().unwrap().len(), 69);
}

#[test]
fn straddling_box_on_real_calibration_gives_finite_pixels() {
    let info = nuscenes_info();
    let cams = frame_cameras(&info);
    // A 12 m bus centred on the sensor cuts through every camera's plane.
    let b = Box3d::new(0.0, 0.0, 0.0, 12.0, 2.5, 3.0, 0.2);
    for cam in &cams {
        let v = view_box(cam, &b);
        assert!(!v.behind, "{}", cam.name);
        assert!(!v.polylines.is_empty(), "{}", cam.name);
        assert!(v.polylines.iter().flatten().all(|p| p[0].is_finite() && p[1].is_finite()));
    }
}

#[test]
fn pi3det_sample_uses_its_calib_and_a_default_canvas() {
    let data = shared("pi3det_sample");
    let ds = pi3det_data::open(&data).unwrap();
    let info = ds.info(1).unwrap();
    assert_eq!(info.cameras.len(), 1);
    let c = &info.cameras[0];
    assert!(c.image_path.as_ref().unwrap().ends_with("training/image/0000001.jpg"));
    let out = tempfile::tempdir().unwrap();
    let mut opts = options(data, out.path());
    opts.frames = Some(FrameRange { start: 1, end: Some(2) });
    let report = project::project(&opts).unwrap();
    let cam = &report.frames[0].cameras[0];
    assert_eq!((cam.image.as_str(), cam.width, cam.height), ("none, canvas", 1280, 800));
    // The same KITTI frame 000001: its three boxes are in front of the camera.
    assert_eq!(report.frames[0].boxes.len(), 3);
    assert_eq!(report.summary.behind_all_cameras, 0);
}

#[test]
fn detections_are_drawn_and_flagged() {
    let data = shared("kitti/training");
    let dir = tempfile::tempdir().unwrap();
    let det = dir.path().join("dets.jsonl");
    // One box ahead, one behind the camera, one far to the side.
    std::fs::write(
        &det,
        r#"{"frame_id": "000001", "names": ["Car", "Car", "Pedestrian"], "scores": [0.9, 0.5, 0.3], "boxes_lidar": [[15.0, 0.0, -0.8, 4.0, 1.8, 1.5, 0.0], [-15.0, 0.0, -0.8, 4.0, 1.8, 1.5, 0.0], [2.0, 30.0, -0.8, 0.6, 0.6, 1.7, 0.0]]}"#,
    )
    .unwrap();
    let out = dir.path().join("out");
    let mut opts = options(data, &out);
    opts.det = Some(det);
    opts.frames = Some("1".parse().unwrap());
    opts.verify_cmd = Some("test -s {crop} && echo checked {class}".into());
    let report = project::project(&opts).unwrap();
    let dets: Vec<_> = report.frames[0].boxes.iter().filter(|b| b.source == Source::Det).collect();
    assert_eq!(dets.len(), 3);
    assert_eq!((dets[0].flag, dets[0].score), (None, Some(0.9)));
    assert_eq!(dets[0].verify.as_deref(), Some("checked Car"));
    assert_eq!(dets[1].flag, Some(Flag::BehindAllCameras));
    assert_eq!(dets[2].flag, Some(Flag::OutsideAllImages));
    assert_eq!(dets[1].verify, None);
    let s = &report.summary;
    assert_eq!((s.boxes_gt, s.boxes_det, s.behind_all_cameras, s.outside_all_images), (3, 3, 1, 1));
    assert!(s.to_string().contains("6 boxes (3 gt, 3 det): 4 seen, 1 outside all images, 1 behind all cameras"));
}

#[test]
fn frame_without_calibration_is_reported_not_fatal() {
    let mut info = FrameInfo::new("x", PathBuf::from("x.bin"));
    info.objects.push(pi3det_data::Object::new("Car", Box3d::new(5.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0)));
    let out = tempfile::tempdir().unwrap();
    let opts = options(PathBuf::from("mem"), out.path());
    let r = project_frame(0, &info, &frame_items(&info, &[], None), &opts, None).unwrap();
    assert!(r.message.as_deref().unwrap().contains("no calibration"));
    assert_eq!(r.boxes.len(), 1);
    assert!(r.cameras.is_empty());
}

#[test]
fn unknown_camera_lists_the_cameras() {
    let data = nuscenes_pkl();
    let out = tempfile::tempdir().unwrap();
    let mut opts = options(data, &out.path().join("o"));
    opts.cameras = vec!["CAM_FRONT".into(), "CAM_TOP".into()];
    let e = project::project(&opts).unwrap_err().to_string();
    assert!(e.contains("--camera CAM_TOP") && e.contains("CAM_FRONT, ") && e.contains("CAM_BACK_LEFT"), "{e}");
    assert!(!out.path().join("o").exists());
    opts.cameras = vec!["CAM_BACK".into()];
    opts.overwrite = true;
    let r = project::project(&opts).unwrap();
    assert_eq!(r.frames[0].cameras.len(), 1);
}

#[test]
fn detections_of_unknown_frames_are_an_error() {
    let data = shared("kitti/training");
    let dir = tempfile::tempdir().unwrap();
    let det = dir.path().join("dets.jsonl");
    std::fs::write(&det, r#"{"frame_id": "999999", "names": [], "scores": [], "boxes_lidar": []}"#).unwrap();
    let mut opts = options(data, &dir.path().join("out"));
    opts.det = Some(det.clone());
    let e = project::project(&opts).unwrap_err().to_string();
    assert!(e.contains(&det.display().to_string()) && e.contains("\"999999\""), "{e}");
    assert!(!dir.path().join("out").exists(), "nothing is written before the inputs check out");
}

#[test]
fn existing_output_needs_overwrite() {
    let data = shared("kitti/training");
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("keep.txt"), "x").unwrap();
    let mut opts = options(data, dir.path());
    opts.frames = Some("0..1".parse().unwrap());
    let e = project::project(&opts).unwrap_err().to_string();
    assert!(e.contains("--overwrite") && e.contains(&dir.path().display().to_string()), "{e}");
    opts.overwrite = true;
    project::project(&opts).unwrap();
    assert!(dir.path().join("000000_image_2.jpg").exists() && dir.path().join("keep.txt").exists());
    // An empty --out is fine without it; a range past the data is an error.
    let empty = tempfile::tempdir().unwrap();
    opts.out = empty.path().to_path_buf();
    opts.overwrite = false;
    opts.frames = Some("10..12".parse().unwrap());
    assert!(project::project(&opts).unwrap_err().to_string().contains("selects no frame"));
    assert!("a..b".parse::<FrameRange>().is_err());
    assert_eq!("..3".parse::<FrameRange>().unwrap(), FrameRange { start: 0, end: Some(3) });
}

/// A written Pi3DET dataset: frame 0 with a distorting camera and a 320×200 image, frame 1
/// without calibration.
fn write_pi3det(root: &Path) {
    use pi3det_data::pi3det::Pi3detWriter;
    use pi3det_data::{Calib, Frame, Object, PointCloud};
    let image = root.join("training/image/0000000.png");
    std::fs::create_dir_all(image.parent().unwrap()).unwrap();
    image::RgbImage::from_pixel(320, 200, image::Rgb([90, 90, 200])).save(&image).unwrap();
    // LiDAR x forward → camera z; camera x = −y, camera y = −z.
    let e = [[0., -1., 0., 0.], [0., 0., -1., 0.], [1., 0., 0., 0.], [0., 0., 0., 1.]];
    let k = [[200., 0., 160.], [0., 200., 100.], [0., 0., 1.]];
    let mut w = Pi3detWriter::create(root, "val", false).unwrap();
    for id in ["0000000", "0000001"] {
        let mut info = FrameInfo::new(id, PathBuf::new());
        info.objects.push(Object::new("Car", Box3d::new(8.0, 0.5, 0.0, 4.0, 1.8, 1.5, 0.1)));
        if id == "0000000" {
            info.calib = Some(Calib::Pinhole {
                camera_from_lidar: e,
                intrinsics: k,
                distortion: vec![-0.1, 0.01, 0.0, 0.0, 0.0],
            });
            info.cameras.push(CameraInfo {
                name: "camera".into(),
                image_path: Some(image.clone()),
                camera_from_lidar: e,
                intrinsics: k,
                distortion: vec![-0.1, 0.01, 0.0, 0.0, 0.0],
                image_size: None,
            });
        }
        w.write_frame(&Frame { info, points: PointCloud::from_xyzi(&[[1.0, 2.0, 3.0, 0.5]]) }).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn pi3det_distortion_image_and_missing_calibration_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    write_pi3det(dir.path());
    let ds = pi3det_data::open(dir.path()).unwrap();
    let info = ds.info(0).unwrap();
    assert_eq!(info.cameras.len(), 1, "the reader keeps calib and image_path");
    assert_eq!(info.cameras[0].image_path.as_deref(), Some(dir.path().join("training/image/0000000.png").as_path()));
    let cam = CameraModel::from_info(&info.cameras[0]);
    // LiDAR (10, −3, 1) → camera (3, −1, 10) → (0.3, −0.1), r² = 0.1,
    // factor 1 − 0.1·0.1 + 0.01·0.01 = 0.9901 → u = 160 + 200·0.29703, v = 100 − 200·0.09901.
    let [u, v] = cam.project([10.0, -3.0, 1.0]).unwrap();
    assert!((u - 219.406).abs() < 1e-9 && (v - 80.198).abs() < 1e-9, "{u} {v}");
    let out = dir.path().join("out");
    let report = project::project(&options(dir.path().to_path_buf(), &out)).unwrap();
    let (f0, f1) = (&report.frames[0], &report.frames[1]);
    assert_eq!((f0.cameras[0].width, f0.cameras[0].height), (320, 200));
    assert!(f0.cameras[0].image.ends_with("0000000.png"));
    assert_eq!(f0.boxes[0].cameras, ["camera"]);
    assert!(f1.message.as_deref().unwrap().contains("no calibration") && f1.cameras.is_empty());
    let s = &report.summary;
    assert_eq!((s.frames, s.images_written, s.frames_without_calibration, s.unchecked), (2, 1, 1, 1));
    assert!(s.to_string().contains("1 frames without calibration (1 boxes unchecked)"), "{s}");
    // The drawing is the image with the box on it.
    let drawn = image::open(out.join(&f0.cameras[0].output)).unwrap().to_rgb8();
    assert_eq!(drawn.dimensions(), (320, 200));
    assert!(drawn.pixels().filter(|p| p.0[1] > 180 && p.0[2] < 120).count() > 50, "green edges expected");
}

#[test]
fn kitti_result_folder_boxes_go_back_through_the_calibration() {
    let data = shared("kitti/training");
    let dir = tempfile::tempdir().unwrap();
    let det = dir.path().join("results");
    std::fs::create_dir(&det).unwrap();
    // Frame 000001's labels with a score column: the camera boxes must land where the gt does.
    let labels = std::fs::read_to_string(data.join("label_2/000001.txt")).unwrap();
    let lines: String = labels.lines().filter(|l| !l.starts_with("DontCare")).map(|l| format!("{l} 0.75\n")).collect();
    std::fs::write(det.join("000001.txt"), lines).unwrap();
    let mut opts = options(data, &dir.path().join("out"));
    opts.det = Some(det);
    opts.frames = Some("1".parse().unwrap());
    let report = project::project(&opts).unwrap();
    let boxes = &report.frames[0].boxes;
    assert_eq!(boxes.len(), 6);
    for (g, d) in boxes[..3].iter().zip(&boxes[3..]) {
        assert_eq!((g.source, d.source, d.score), (Source::Gt, Source::Det, Some(0.75)));
        assert_eq!(g.class, d.class);
        assert!(g.box_lidar.iter().zip(d.box_lidar).all(|(a, b)| (a - b).abs() < 1e-3), "{g:?} {d:?}");
        assert_eq!(d.cameras, ["image_2"]);
    }
}
