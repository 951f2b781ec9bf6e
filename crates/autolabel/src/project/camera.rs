//! Camera models: LiDAR → camera coordinates → (distorted) pixels, as OpenCV's `projectPoints`
//! with the plumb-bob model (`k1 k2 p1 p2 k3`).

use std::path::PathBuf;

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
use pi3det_data::CameraInfo;

/// Points closer than this to the camera plane (metres, camera z) count as behind it; edges are
/// clipped here so nothing is divided by a z near 0.
pub const NEAR: f64 = 0.1;

/// One camera ready to project.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraModel {
    pub name: String,
    pub image_path: Option<PathBuf>,
    pub camera_from_lidar: Matrix4<f64>,
    pub intrinsics: Matrix3<f64>,
    /// `k1 k2 p1 p2 k3`, zeros where the calibration had fewer.
    pub distortion: [f64; 5],
    /// Normalised radius (`√(x² + y²)` at z = 1) up to which the radial polynomial grows; beyond
    /// it plumb-bob folds back onto the image, so such points are not projected.
    pub max_radius: f64,
    /// `[width, height]` the calibration expects (the image's own size replaces it when read).
    pub size: Option<[u32; 2]>,
}

impl CameraModel {
    pub fn new(name: impl Into<String>, camera_from_lidar: Matrix4<f64>, intrinsics: Matrix3<f64>, d: &[f64]) -> Self {
        let distortion = std::array::from_fn(|i| d.get(i).copied().unwrap_or(0.0));
        Self {
            name: name.into(),
            image_path: None,
            camera_from_lidar,
            intrinsics,
            distortion,
            max_radius: monotone_radius(&distortion),
            size: None,
        }
    }

    pub fn from_info(c: &CameraInfo) -> Self {
        let e = Matrix4::from_fn(|i, j| c.camera_from_lidar[i][j]);
        let k = Matrix3::from_fn(|i, j| c.intrinsics[i][j]);
        let mut m = Self::new(c.name.clone(), e, k, &c.distortion);
        m.image_path = c.image_path.clone();
        m.size = c.image_size;
        m
    }

    pub fn has_distortion(&self) -> bool {
        self.distortion.iter().any(|&d| d != 0.0)
    }

    /// A LiDAR point in camera coordinates (z forward).
    pub fn to_camera(&self, p: [f64; 3]) -> Vector3<f64> {
        let q = self.camera_from_lidar * Vector4::new(p[0], p[1], p[2], 1.0);
        Vector3::new(q.x, q.y, q.z)
    }

    /// Pixels of a camera-frame point; `None` in front of the near plane or where the distortion
    /// model no longer holds.
    pub fn camera_to_pixel(&self, q: Vector3<f64>) -> Option<[f64; 2]> {
        if !q.z.is_finite() || q.z < NEAR {
            return None;
        }
        let (x, y) = (q.x / q.z, q.y / q.z);
        let (x, y) = if self.has_distortion() {
            if (x * x + y * y).sqrt() > self.max_radius {
                return None;
            }
            distort(x, y, &self.distortion)
        } else {
            (x, y)
        };
        let p = self.intrinsics * Vector3::new(x, y, 1.0);
        (p.z.abs() > 1e-12).then(|| [p.x / p.z, p.y / p.z]).filter(|[u, v]| u.is_finite() && v.is_finite())
    }

    /// Pixels of a LiDAR point.
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        self.camera_to_pixel(self.to_camera(p))
    }
}

/// OpenCV plumb-bob on normalised coordinates `(x, y) = (X/Z, Y/Z)`.
pub fn distort(x: f64, y: f64, d: &[f64; 5]) -> (f64, f64) {
    let [k1, k2, p1, p2, k3] = *d;
    let r2 = x * x + y * y;
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)
}

/// The first radius (searched up to 10, i.e. ±84° off axis) where `r·(1 + k1 r² + k2 r⁴ + k3 r⁶)`
/// stops growing.
fn monotone_radius(d: &[f64; 5]) -> f64 {
    let [k1, k2, _, _, k3] = *d;
    let slope = |r: f64| {
        let r2 = r * r;
        1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2 + 7.0 * k3 * r2 * r2 * r2
    };
    let step = 1e-3;
    let mut r = 0.0;
    while r < 10.0 {
        if slope(r + step) <= 0.0 {
            return r;
        }
        r += step;
    }
    f64::INFINITY
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(d: &[f64]) -> CameraModel {
        let k = Matrix3::new(1000.0, 0.0, 640.0, 0.0, 1000.0, 400.0, 0.0, 0.0, 1.0);
        CameraModel::new("c", Matrix4::identity(), k, d)
    }

    #[test]
    fn zero_distortion_is_pinhole() {
        let (a, b) = (camera(&[]), camera(&[0.0; 5]));
        for p in [[0.5, -0.3, 4.0], [-2.0, 1.0, 10.0], [0.0, 0.0, 1.0]] {
            let pin = [640.0 + 1000.0 * p[0] / p[2], 400.0 + 1000.0 * p[1] / p[2]];
            assert_eq!(a.project(p), Some(pin));
            assert_eq!(b.project(p), Some(pin));
        }
    }

    #[test]
    fn k1_by_hand() {
        // x = 0.5, y = 0: r² = 0.25, factor 1 + 0.1·0.25 = 1.025 → x' = 0.5125 → u = 640 + 512.5.
        let c = camera(&[0.1]);
        let [u, v] = c.project([1.0, 0.0, 2.0]).unwrap();
        assert!((u - 1152.5).abs() < 1e-9, "{u}");
        assert!((v - 400.0).abs() < 1e-9, "{v}");
        // Tangential: p1 = 0.01 at (0.5, 0.5): y' = 0.5 + 0.01·(0.5 + 0.5) = 0.51 (x' gains 2·p1·xy = 0.005).
        let (x, y) = distort(0.5, 0.5, &[0.0, 0.0, 0.01, 0.0, 0.0]);
        assert!((x - 0.505).abs() < 1e-12 && (y - 0.51).abs() < 1e-12, "{x} {y}");
    }

    #[test]
    fn behind_and_folded_points_are_not_projected() {
        let c = camera(&[]);
        assert_eq!(c.project([0.0, 0.0, -1.0]), None);
        assert_eq!(c.project([0.0, 0.0, NEAR / 2.0]), None);
        // k1 < 0: r(1 + k1 r²) peaks at r = 1/√(3·0.2) ≈ 1.29.
        let c = camera(&[-0.2]);
        assert!((c.max_radius - 1.29).abs() < 0.01, "{}", c.max_radius);
        assert!(c.project([1.0, 0.0, 1.0]).is_some());
        assert_eq!(c.project([3.0, 0.0, 1.0]), None);
    }
}
