//! Ground truth and detections of one frame in the reference's camera-frame form.
//!
//! Frames with a KITTI calibration are evaluated as OpenPCDet evaluates KITTI: boxes in the
//! rectified camera frame through the calibration, ground-truth truncation / occlusion / 2D box /
//! alpha from the labels, detections' 2D box and alpha from the detection file or, for LiDAR
//! boxes without them, projected as OpenPCDet's `generate_prediction_dicts` does. Every other
//! frame (Pi3DET, nuScenes, ...) gets OpenPCDet's `transform_annotations_to_kitti_format`: the
//! identity "fake" camera, a 50 px 2D box, truncation and occlusion 0 (easy = moderate = hard),
//! for ground truth and detections alike.

use pi3det_data::{Calib, FrameInfo};
use pi3det_geometry::kitti::{alpha_from_lidar, fake_camera_box, CameraBox, KittiCalib, FAKE_BBOX_2D};
use pi3det_geometry::Box3d;

use crate::anno::{KittiFrame, KittiObject};
use crate::classes::NameMap;
use crate::detections::Detection;

/// How boxes of a frame reach the camera frame.
#[derive(Clone, Copy)]
pub(crate) enum Camera<'a> {
    Kitti(&'a KittiCalib),
    Fake,
}

impl<'a> Camera<'a> {
    pub fn of(info: &'a FrameInfo) -> Self {
        match &info.calib {
            Some(Calib::Kitti(c)) => Camera::Kitti(c),
            _ => Camera::Fake,
        }
    }

    fn lidar_box(&self, b: &Box3d) -> CameraBox {
        match self {
            Camera::Kitti(c) => c.lidar_to_camera(b),
            Camera::Fake => fake_camera_box(b).0,
        }
    }

    /// Camera box back to the LiDAR frame (the inverse of `lidar_box`).
    fn camera_to_lidar(&self, c: &CameraBox) -> Box3d {
        match self {
            Camera::Kitti(k) => k.camera_to_lidar(c),
            Camera::Fake => {
                let [l, h, w] = c.dimensions_lhw;
                let [x, y, z] = c.location;
                Box3d::new(z, -x, -y + 0.5 * h, l, w, h, -(c.rotation_y + std::f64::consts::FRAC_PI_2))
            }
        }
    }

    /// BEV centre in the LiDAR frame of a camera box (for the range filter).
    fn lidar_xy(&self, c: &CameraBox) -> [f64; 2] {
        match self {
            Camera::Kitti(k) => {
                let p = k.rect_to_lidar(c.location);
                [p[0], p[1]]
            }
            Camera::Fake => [c.location[2], -c.location[0]],
        }
    }
}

/// Filters applied before evaluation.
pub(crate) struct Filter<'a> {
    pub names: &'a NameMap,
    pub score_threshold: Option<f64>,
    pub bev_range: Option<[f64; 4]>,
    pub image_size: [f64; 2],
}

impl Filter<'_> {
    fn in_range(&self, xy: [f64; 2]) -> bool {
        self.bev_range.is_none_or(|r| xy[0] >= r[0] && xy[0] <= r[2] && xy[1] >= r[1] && xy[1] <= r[3])
    }
}

/// OpenPCDet's alpha of a LiDAR box: `-atan2(-y, x) + rotation_y`; in the fake camera the LiDAR
/// (x, y) of a camera box are (z, −x).
fn fake_alpha(c: &CameraBox) -> f64 {
    -(c.location[0]).atan2(c.location[2]) + c.rotation_y
}

fn object(
    name: String,
    c: &CameraBox,
    bbox: [f64; 4],
    truncated: f64,
    occluded: f64,
    alpha: f64,
    score: f64,
) -> KittiObject {
    KittiObject {
        name,
        truncated,
        occluded,
        alpha,
        bbox,
        dimensions: c.dimensions_lhw,
        location: c.location,
        rotation_y: c.rotation_y,
        score,
    }
}

/// A kept ground truth in the LiDAR frame, for the error breakdown: its box and the point count
/// the dataset stored.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LidarGt {
    pub box3d: Box3d,
    pub num_points: Option<u32>,
}

pub(crate) fn ground_truth(info: &FrameInfo, f: &Filter) -> KittiFrame {
    ground_truth_lidar(info, f).0
}

/// The ground truth in the reference's form and, for its objects (which come first, before the
/// DontCare regions), their LiDAR boxes.
pub(crate) fn ground_truth_lidar(info: &FrameInfo, f: &Filter) -> (KittiFrame, Vec<LidarGt>) {
    let cam = Camera::of(info);
    let mut objects = Vec::with_capacity(info.objects.len() + info.dont_care.len());
    let mut lidar = Vec::with_capacity(info.objects.len());
    for o in &info.objects {
        if !f.in_range([o.box3d.x, o.box3d.y]) {
            continue;
        }
        lidar.push(LidarGt { box3d: o.box3d, num_points: o.num_points });
        let name = f.names.map(&o.name);
        let c = cam.lidar_box(&o.box3d);
        let obj = match (cam, &o.kitti) {
            (Camera::Kitti(_), Some(k)) => object(name, &c, k.bbox_2d, k.truncation, k.occlusion as f64, k.alpha, 0.0),
            (Camera::Kitti(_), None) => {
                object(name, &c, FAKE_BBOX_2D, 0.0, 0.0, alpha_from_lidar(&o.box3d, c.rotation_y), 0.0)
            }
            (Camera::Fake, _) => object(name, &c, FAKE_BBOX_2D, 0.0, 0.0, fake_alpha(&c), 0.0),
        };
        objects.push(obj);
    }
    // DontCare regions as the label lines the reference reads.
    for bbox in &info.dont_care {
        let c = CameraBox { location: [-1000.0; 3], dimensions_lhw: [-1.0; 3], rotation_y: -10.0 };
        objects.push(object("DontCare".into(), &c, *bbox, -1.0, -1.0, -10.0, 0.0));
    }
    (KittiFrame { id: info.id.clone(), objects }, lidar)
}

/// OpenPCDet's image box of a camera box: the 8 corners projected with P2 divided by the
/// rectified depth (`rect_to_img`), min / max, clipped to the image.
fn image_box(k: &KittiCalib, c: &CameraBox, image_size: [f64; 2]) -> [f64; 4] {
    let [l, h, w] = c.dimensions_lhw;
    let (s, co) = c.rotation_y.sin_cos();
    let xs = [l / 2., l / 2., -l / 2., -l / 2., l / 2., l / 2., -l / 2., -l / 2.];
    let ys = [0., 0., 0., 0., -h, -h, -h, -h];
    let zs = [w / 2., -w / 2., -w / 2., w / 2., w / 2., -w / 2., -w / 2., w / 2.];
    let mut r = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    for i in 0..8 {
        let p =
            [xs[i] * co + zs[i] * s + c.location[0], ys[i] + c.location[1], -xs[i] * s + zs[i] * co + c.location[2]];
        let proj = |row: usize| k.p2[(row, 0)] * p[0] + k.p2[(row, 1)] * p[1] + k.p2[(row, 2)] * p[2] + k.p2[(row, 3)];
        let (u, v) = (proj(0) / p[2], proj(1) / p[2]);
        r = [r[0].min(u), r[1].min(v), r[2].max(u), r[3].max(v)];
    }
    let [wd, ht] = image_size;
    let clip = |v: f64, hi: f64| if v.is_nan() { 0.0 } else { v.clamp(0.0, hi - 1.0) };
    [clip(r[0], wd), clip(r[1], ht), clip(r[2], wd), clip(r[3], ht)]
}

pub(crate) fn detections(info: &FrameInfo, dets: &[Detection], f: &Filter) -> KittiFrame {
    detections_lidar(info, dets, f).0
}

/// The detections in the reference's form and each one's LiDAR box (given, or converted back
/// from its camera box), in the same order.
pub(crate) fn detections_lidar(info: &FrameInfo, dets: &[Detection], f: &Filter) -> (KittiFrame, Vec<Box3d>) {
    let cam = Camera::of(info);
    let mut objects = Vec::with_capacity(dets.len());
    let mut lidar = Vec::with_capacity(dets.len());
    for d in dets {
        if f.score_threshold.is_some_and(|t| d.score < t) {
            continue;
        }
        // Camera boxes are what the reference reads on KITTI; LiDAR boxes elsewhere.
        let c = match (cam, d.camera, d.lidar) {
            (Camera::Kitti(_), Some(c), _) => c,
            (_, _, Some(b)) => cam.lidar_box(&b),
            (_, Some(c), None) => c,
            (_, None, None) => continue,
        };
        let xy = match (&d.lidar, cam) {
            (Some(b), _) => [b.x, b.y],
            (None, _) => cam.lidar_xy(&c),
        };
        if !f.in_range(xy) {
            continue;
        }
        lidar.push(match (cam, d.lidar) {
            // On KITTI frames the camera box is what is evaluated, so its LiDAR form is too.
            (Camera::Kitti(_), _) if d.camera.is_some() => cam.camera_to_lidar(&c),
            (_, Some(b)) => b,
            (_, None) => cam.camera_to_lidar(&c),
        });
        let name = f.names.map(&d.name);
        let obj = match cam {
            Camera::Kitti(k) => {
                let bbox = d.bbox.unwrap_or_else(|| image_box(k, &c, f.image_size));
                let alpha = d.alpha.unwrap_or_else(|| match &d.lidar {
                    Some(b) => alpha_from_lidar(b, c.rotation_y),
                    None => {
                        let [x, y] = cam.lidar_xy(&c);
                        -(-y).atan2(x) + c.rotation_y
                    }
                });
                object(name, &c, bbox, 0.0, 0.0, alpha, d.score)
            }
            Camera::Fake => object(name, &c, FAKE_BBOX_2D, 0.0, 0.0, fake_alpha(&c), d.score),
        };
        objects.push(obj);
    }
    (KittiFrame { id: info.id.clone(), objects }, lidar)
}

/// Puts LiDAR box `b` into a detection of `info` in the reference's form (location, size,
/// rotation; its 2D box, alpha and score stay): for "what if" evaluations.
pub(crate) fn set_detection_box(info: &FrameInfo, obj: &mut KittiObject, b: &Box3d) {
    let c = Camera::of(info).lidar_box(b);
    obj.dimensions = c.dimensions_lhw;
    obj.location = c.location;
    obj.rotation_y = c.rotation_y;
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::Object;
    use std::path::PathBuf;

    fn names() -> NameMap {
        NameMap::new(&crate::classes::default_name_map())
    }

    #[test]
    fn fake_frames_get_the_fake_fields() {
        let mut info = FrameInfo::new("x", PathBuf::new());
        info.objects.push(Object::new("Vehicle", Box3d::new(10.0, 2.0, -0.5, 4.0, 1.8, 1.6, 0.3)));
        let n = names();
        let f = Filter { names: &n, score_threshold: Some(0.2), bev_range: None, image_size: [1242.0, 375.0] };
        let g = ground_truth(&info, &f);
        assert_eq!(g.objects[0].name, "Car");
        assert_eq!(g.objects[0].bbox, FAKE_BBOX_2D);
        let (c, alpha) = fake_camera_box(&info.objects[0].box3d);
        assert_eq!(g.objects[0].location, c.location);
        assert!((g.objects[0].alpha - alpha).abs() < 1e-12);
        let det = |score| Detection {
            name: "Car".into(),
            score,
            lidar: Some(Box3d::new(10.0, 2.0, -0.5, 4.0, 1.8, 1.6, 0.3)),
            camera: None,
            bbox: Some([1.0, 2.0, 3.0, 4.0]),
            alpha: Some(5.0),
        };
        let d = detections(&info, &[det(0.5), det(0.1)], &f);
        assert_eq!(d.objects.len(), 1);
        assert_eq!(d.objects[0].bbox, FAKE_BBOX_2D);
        assert!((d.objects[0].alpha - alpha).abs() < 1e-12);
        let f = Filter { bev_range: Some([0.0, -1.0, 20.0, 1.0]), ..f };
        assert!(ground_truth(&info, &f).objects.is_empty());
    }
}
