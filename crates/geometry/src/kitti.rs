//! KITTI camera boxes and LiDAR boxes, converted through the calibration as OpenPCDet does, plus
//! the "fake KITTI" conversion used to evaluate datasets that have no camera fields.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Vector4};
use serde::{Deserialize, Serialize};

use crate::boxes::Box3d;

/// A KITTI label box in the rectified camera frame: `location` is the bottom centre,
/// `dimensions` are (length, height, width) as in label files, `rotation_y` about camera y.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraBox {
    pub location: [f64; 3],
    pub dimensions_lhw: [f64; 3],
    pub rotation_y: f64,
}

/// The calibration of a KITTI object frame.
#[derive(Debug, Clone, PartialEq)]
pub struct KittiCalib {
    /// Left colour camera projection (rectified camera → image).
    pub p2: Matrix3x4<f64>,
    pub r0_rect: Matrix3<f64>,
    /// `cam_from_velo`: LiDAR → (unrectified) camera 0.
    pub tr_velo_to_cam: Matrix3x4<f64>,
}

fn extend(m: &Matrix3x4<f64>) -> Matrix4<f64> {
    let mut e = Matrix4::identity();
    e.fixed_view_mut::<3, 4>(0, 0).copy_from(m);
    e
}

impl KittiCalib {
    /// `rect_from_lidar` as a homogeneous matrix: `R0_rect · Tr_velo_to_cam`.
    pub fn rect_from_lidar(&self) -> Matrix4<f64> {
        let mut r0 = Matrix4::identity();
        r0.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.r0_rect);
        r0 * extend(&self.tr_velo_to_cam)
    }

    pub fn lidar_to_rect(&self, p: [f64; 3]) -> [f64; 3] {
        let q = self.rect_from_lidar() * Vector4::new(p[0], p[1], p[2], 1.0);
        [q.x, q.y, q.z]
    }

    pub fn rect_to_lidar(&self, p: [f64; 3]) -> [f64; 3] {
        // Rigid in practice, but KITTI's matrices are not exactly orthonormal: invert in general.
        let inv = self.rect_from_lidar().try_inverse().unwrap_or_else(Matrix4::identity);
        let q = inv * Vector4::new(p[0], p[1], p[2], 1.0);
        [q.x, q.y, q.z]
    }

    /// Projects a rectified-camera point to pixels; `None` behind the camera.
    pub fn rect_to_image(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let q = self.p2 * Vector4::new(p[0], p[1], p[2], 1.0);
        (q.z > 1e-6).then(|| [q.x / q.z, q.y / q.z])
    }

    /// Camera box → LiDAR box (OpenPCDet `boxes3d_kitti_camera_to_lidar`).
    pub fn camera_to_lidar(&self, c: &CameraBox) -> Box3d {
        let [l, h, w] = c.dimensions_lhw;
        let [x, y, z] = self.rect_to_lidar(c.location);
        Box3d::new(x, y, z + 0.5 * h, l, w, h, -(c.rotation_y + std::f64::consts::FRAC_PI_2))
    }

    /// LiDAR box → camera box (OpenPCDet `boxes3d_lidar_to_kitti_camera`).
    pub fn lidar_to_camera(&self, b: &Box3d) -> CameraBox {
        let location = self.lidar_to_rect([b.x, b.y, b.z - 0.5 * b.dz]);
        CameraBox { location, dimensions_lhw: [b.dx, b.dz, b.dy], rotation_y: -b.heading - std::f64::consts::FRAC_PI_2 }
    }

    /// The 2D image box `[x1, y1, x2, y2]` of a LiDAR box, clipped to the image when a size
    /// `(width, height)` is given; `None` when a corner is behind the camera.
    pub fn image_box(&self, b: &Box3d, image_wh: Option<[f64; 2]>) -> Option<[f64; 4]> {
        let mut r = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        for c in b.corners() {
            let [u, v] = self.rect_to_image(self.lidar_to_rect([c.x, c.y, c.z]))?;
            r = [r[0].min(u), r[1].min(v), r[2].max(u), r[3].max(v)];
        }
        if let Some([w, h]) = image_wh {
            r = [
                r[0].clamp(0.0, w - 1.0),
                r[1].clamp(0.0, h - 1.0),
                r[2].clamp(0.0, w - 1.0),
                r[3].clamp(0.0, h - 1.0),
            ];
        }
        Some(r)
    }
}

/// Observation angle as OpenPCDet writes it for predictions: `-atan2(-y, x) + rotation_y`.
pub fn alpha_from_lidar(b: &Box3d, rotation_y: f64) -> f64 {
    -(-b.y).atan2(b.x) + rotation_y
}

/// The 2D box given to every object of a dataset without camera fields (reference §3): with
/// occlusion 0 and truncation 0 every object is "easy", so easy = moderate = hard.
pub const FAKE_BBOX_2D: [f64; 4] = [0.0, 0.0, 50.0, 50.0];

/// OpenPCDet's `transform_annotations_to_kitti_format`: a camera box with an identity calibration
/// (camera x = −LiDAR y, camera y = −LiDAR z, camera z = LiDAR x), and its alpha.
pub fn fake_camera_box(b: &Box3d) -> (CameraBox, f64) {
    let rotation_y = -b.heading - std::f64::consts::FRAC_PI_2;
    let cam = CameraBox { location: [-b.y, -(b.z - 0.5 * b.dz), b.x], dimensions_lhw: [b.dx, b.dz, b.dy], rotation_y };
    (cam, alpha_from_lidar(b, rotation_y))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Calibration of KITTI training frame 000000.
    fn calib() -> KittiCalib {
        KittiCalib {
            p2: Matrix3x4::from_row_slice(&[
                7.070493e2,
                0.0,
                6.040814e2,
                4.575831e1,
                0.0,
                7.070493e2,
                1.805066e2,
                -3.454157e-1,
                0.0,
                0.0,
                1.0,
                4.981016e-3,
            ]),
            r0_rect: Matrix3::from_row_slice(&[
                9.999128e-1,
                1.009263e-2,
                -8.511932e-3,
                -1.012729e-2,
                9.999406e-1,
                -4.037671e-3,
                8.470675e-3,
                4.123522e-3,
                9.999556e-1,
            ]),
            tr_velo_to_cam: Matrix3x4::from_row_slice(&[
                6.927964e-3,
                -9.999722e-1,
                -2.757829e-3,
                -2.457729e-2,
                -1.162982e-3,
                2.749836e-3,
                -9.999955e-1,
                -6.127237e-2,
                9.999753e-1,
                6.931141e-3,
                -1.143899e-3,
                -3.32586e-1,
            ]),
        }
    }

    #[test]
    fn camera_lidar_round_trip() {
        let c = CameraBox { location: [1.84, 1.47, 8.41], dimensions_lhw: [1.2, 1.89, 0.48], rotation_y: 0.01 };
        let k = calib();
        let b = k.camera_to_lidar(&c);
        // The pedestrian of frame 000000 sits about 8.7 m ahead, 1.8 m to the right.
        assert!((b.x - 8.7).abs() < 0.1 && (b.y + 1.8).abs() < 0.1, "{b:?}");
        let back = k.lidar_to_camera(&b);
        for (a, e) in back.location.iter().zip(c.location) {
            assert!((a - e).abs() < 1e-9);
        }
        assert!((back.rotation_y - c.rotation_y).abs() < 1e-12);
        assert_eq!(back.dimensions_lhw, c.dimensions_lhw);
        let bb = k.image_box(&b, Some([1242.0, 375.0])).unwrap();
        // Label line: 712.40 143.00 810.73 307.92 (the label's own 2D box, not a projection).
        assert!((bb[0] - 712.4).abs() < 15.0 && (bb[3] - 307.9).abs() < 15.0, "{bb:?}");
    }

    #[test]
    fn fake_conversion_matches_openpcdet() {
        let b = Box3d::new(10.0, 2.0, -0.5, 4.0, 1.8, 1.6, 0.3);
        let (c, alpha) = fake_camera_box(&b);
        assert_eq!(c.location, [-2.0, 1.3, 10.0]);
        assert_eq!(c.dimensions_lhw, [4.0, 1.6, 1.8]);
        assert!((c.rotation_y - (-0.3 - std::f64::consts::FRAC_PI_2)).abs() < 1e-15);
        assert!((alpha - (-(-2.0f64).atan2(10.0) + c.rotation_y)).abs() < 1e-15);
    }
}
