//! Readers on the real frames in `../shared/data`: KITTI, the Pi3DET layout and nuScenes.

mod common;

use common::shared_data;
use pi3det_data::{open, Format, Platform};
use pi3det_geometry::{iou_3d, Box3d};

#[test]
fn kitti_frame_000001() {
    let ds = open(&shared_data("kitti/training")).unwrap();
    assert_eq!(ds.format(), Format::Kitti);
    assert_eq!(ds.len(), 6);
    let info = ds.info(1).unwrap();
    assert_eq!(info.id, "000001");
    let names: Vec<&str> = info.objects.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names, ["Truck", "Car", "Cyclist"]);
    assert_eq!(info.dont_care.len(), 4);
    assert_eq!(info.dont_care[0], [503.89, 169.71, 590.61, 190.13]);
    let cyclist = info.objects[2].kitti.unwrap();
    assert_eq!((cyclist.occlusion, cyclist.truncation), (3, 0.0));
    // The truck is 69 m ahead, 12.34 m long, lying along the LiDAR x axis.
    let truck = info.objects[0].box3d;
    assert!((truck.x - 69.72).abs() < 0.05 && truck.dx == 12.34, "{truck:?}");
    let frame = ds.load(1).unwrap();
    assert!(frame.points.len() > 100_000);
    assert_eq!(frame.points.stride(), 4);
}

#[test]
fn pi3det_sample_matches_kitti_originals() {
    let pi = open(&shared_data("pi3det_sample")).unwrap();
    let kitti = open(&shared_data("kitti/training")).unwrap();
    assert_eq!(pi.format(), Format::Pi3det);
    assert_eq!(pi.len(), kitti.len());
    for i in 0..pi.len() {
        let (a, b) = (pi.info(i).unwrap(), kitti.info(i).unwrap());
        assert_eq!(a.platform, Platform::Vehicle);
        let names_a: Vec<&str> = a.objects.iter().map(|o| o.name.as_str()).collect();
        let names_b: Vec<&str> = b.objects.iter().map(|o| o.name.as_str()).collect();
        assert_eq!(names_a, names_b, "frame {i}");
        for (oa, ob) in a.objects.iter().zip(&b.objects) {
            // float32 storage in the pickle: agree to a millimetre and identical in IoU terms.
            let (ba, bb): (Box3d, Box3d) = (oa.box3d, ob.box3d);
            for (x, y) in ba.to_array().iter().zip(bb.to_array()) {
                assert!((x - y).abs() < 2e-3, "frame {i}: {ba:?} vs {bb:?}");
            }
            assert!(iou_3d(&ba, &bb) > 0.999);
        }
        let (fa, fb) = (pi.load(i).unwrap(), kitti.load(i).unwrap());
        assert_eq!(fa.points.as_slice(), fb.points.as_slice());
    }
}

#[test]
fn nuscenes_points_in_boxes_match_num_lidar_pts() {
    let ds = open(&shared_data("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl")).unwrap();
    assert_eq!(ds.format(), Format::Nuscenes);
    let frame = ds.load(0).unwrap();
    assert_eq!(frame.points.len(), 34_688);
    assert_eq!(frame.points.stride(), 5);
    assert_eq!(frame.info.objects.len(), 69);
    assert!(frame.info.objects.iter().any(|o| o.name == "pedestrian"));
    let counts = frame.points_per_object();
    let (mut exact, mut close) = (0, 0);
    for (o, &n) in frame.info.objects.iter().zip(&counts) {
        let stored = o.num_points.expect("num_lidar_pts") as usize;
        exact += (n == stored) as usize;
        close += (n.abs_diff(stored) as f64 <= (0.05 * stored as f64).max(2.0)) as usize;
    }
    assert!(exact >= 61, "only {exact} of 69 boxes reproduce num_lidar_pts exactly");
    assert!(close >= 68, "only {close} of 69 boxes within max(2, 5%)");
    // lidar2ego puts the sensor about 1.84 m above the ego origin.
    let pose = frame.info.world_from_lidar.expect("pose from ego2global · lidar2ego");
    assert!(pose.translation.vector.norm() > 100.0);
}

/// Every reader brings intensity to [0, 1]: KITTI stores reflectance in [0, 1] already, nuScenes
/// its 8-bit intensity (divided by 255), and Argoverse's converter lost it (1.0 everywhere),
/// which the load reports as constant.
#[test]
fn each_reader_delivers_intensity_in_zero_to_one() {
    use pi3det_data::{IntensityCheck, IntensityScale};
    let range = |f: &pi3det_data::Frame| {
        let i: Vec<f32> = (0..f.points.len()).map(|k| f.points.intensity(k).unwrap()).collect();
        let lo = i.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = i.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        (lo, hi, i.iter().map(|&v| v as f64).sum::<f64>() / i.len() as f64)
    };
    let kitti = open(&shared_data("kitti/training")).unwrap();
    assert_eq!(kitti.info(0).unwrap().intensity_scale, IntensityScale::Unit);
    let (lo, hi, _) = range(&kitti.load(0).unwrap());
    assert!(lo >= 0.0 && hi <= 1.0 && hi > 0.9, "{lo} {hi}");

    let nus = open(&shared_data("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl")).unwrap();
    assert_eq!(nus.info(0).unwrap().intensity_scale, IntensityScale::Byte);
    let frame = nus.load(0).unwrap();
    let (lo, hi, mean) = range(&frame);
    // The file holds 0..=255 (mean 19.85); loaded it is that over 255.
    assert!(lo == 0.0 && hi == 1.0 && (mean - 19.851 / 255.0).abs() < 1e-3, "{lo} {hi} {mean}");
    let raw = pi3det_data::read_bin(&frame.info.points_path, &["x", "y", "z", "intensity", "ring"]).unwrap().cloud;
    for k in (0..raw.len()).step_by(997) {
        assert_eq!(frame.points.point(k)[3], raw.point(k)[3] / 255.0);
        assert_eq!(&frame.points.point(k)[..3], &raw.point(k)[..3]);
        assert_eq!(frame.points.point(k)[4], raw.point(k)[4], "the ring channel is left alone");
    }

    let argo = open(&shared_data("argoverse1/training")).unwrap();
    let f = argo.load(0).unwrap();
    let mut points = pi3det_data::read_bin(&f.info.points_path, &["x", "y", "z", "intensity"]).unwrap().cloud;
    assert_eq!(points.normalize_intensity(IntensityScale::Unit), IntensityCheck::Constant(1.0));
}
