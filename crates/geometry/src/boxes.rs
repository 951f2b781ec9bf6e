//! The 7-DoF upright box used everywhere in pi3det.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::pose::Pose;
use crate::GeometryError;

/// An upright 3D box in the LiDAR frame: centre `(x, y, z)` (z at the box centre, not the bottom),
/// sizes `dx` along the heading direction, `dy` across it, `dz` up, and `heading` (rad) the yaw of
/// the box's x axis measured counter-clockwise from the LiDAR x axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Box3d {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub dx: f64,
    pub dy: f64,
    pub dz: f64,
    pub heading: f64,
}

impl Box3d {
    pub const fn new(x: f64, y: f64, z: f64, dx: f64, dy: f64, dz: f64, heading: f64) -> Self {
        Self { x, y, z, dx, dy, dz, heading }
    }

    /// From `[x, y, z_center, dx, dy, dz, heading]`.
    pub const fn from_array(a: [f64; 7]) -> Self {
        Self::new(a[0], a[1], a[2], a[3], a[4], a[5], a[6])
    }

    /// From the array, rejecting non-finite values and negative sizes (user data).
    pub fn try_from_array(a: [f64; 7]) -> Result<Self, GeometryError> {
        if a.iter().any(|v| !v.is_finite()) {
            return Err(GeometryError::NonFiniteBox(a));
        }
        if a[3] < 0.0 || a[4] < 0.0 || a[5] < 0.0 {
            return Err(GeometryError::NegativeSize(a));
        }
        Ok(Self::from_array(a))
    }

    pub const fn to_array(&self) -> [f64; 7] {
        [self.x, self.y, self.z, self.dx, self.dy, self.dz, self.heading]
    }

    pub fn center(&self) -> Point3<f64> {
        Point3::new(self.x, self.y, self.z)
    }

    pub fn volume(&self) -> f64 {
        self.dx * self.dy * self.dz
    }

    pub fn bottom(&self) -> f64 {
        self.z - 0.5 * self.dz
    }

    pub fn top(&self) -> f64 {
        self.z + 0.5 * self.dz
    }

    /// BEV corners, counter-clockwise for positive sizes, starting at (+dx/2, +dy/2) in box frame.
    pub fn bev_corners(&self) -> [[f64; 2]; 4] {
        let (s, c) = self.heading.sin_cos();
        let (hx, hy) = (0.5 * self.dx, 0.5 * self.dy);
        [(hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy)].map(|(u, v)| [self.x + c * u - s * v, self.y + s * u + c * v])
    }

    /// The 8 corners in OpenPCDet's order: bottom face (z−) then top face (z+), each starting at
    /// (+dx/2, +dy/2) and going (+,+) (−,+)... as `boxes_to_corners_3d`:
    /// `[+,+,-] [+,-,-] [-,-,-] [-,+,-] [+,+,+] [+,-,+] [-,-,+] [-,+,+]`.
    pub fn corners(&self) -> [Point3<f64>; 8] {
        const TEMPLATE: [[f64; 3]; 8] = [
            [1., 1., -1.],
            [1., -1., -1.],
            [-1., -1., -1.],
            [-1., 1., -1.],
            [1., 1., 1.],
            [1., -1., 1.],
            [-1., -1., 1.],
            [-1., 1., 1.],
        ];
        let (s, c) = self.heading.sin_cos();
        TEMPLATE.map(|[u, v, w]| {
            let (u, v, w) = (0.5 * u * self.dx, 0.5 * v * self.dy, 0.5 * w * self.dz);
            Point3::new(self.x + c * u - s * v, self.y + s * u + c * v, self.z + w)
        })
    }

    /// Point in the box's own frame (origin at centre, x along heading).
    #[inline]
    pub fn to_local(&self, p: [f64; 3]) -> [f64; 3] {
        let (s, c) = self.heading.sin_cos();
        let (tx, ty) = (p[0] - self.x, p[1] - self.y);
        [c * tx + s * ty, -s * tx + c * ty, p[2] - self.z]
    }

    /// Inclusive inside test (points exactly on a face count), as the field's `points_in_boxes`.
    #[inline]
    pub fn contains(&self, p: [f64; 3]) -> bool {
        let [u, v, w] = self.to_local(p);
        u.abs() <= 0.5 * self.dx && v.abs() <= 0.5 * self.dy && w.abs() <= 0.5 * self.dz
    }

    /// Number of points inside; `xyz` yields point coordinates.
    pub fn count_points<I: IntoIterator<Item = [f64; 3]>>(&self, xyz: I) -> usize {
        let r2 = 0.25 * (self.dx * self.dx + self.dy * self.dy);
        let (bottom, top) = (self.bottom(), self.top());
        xyz.into_iter()
            .filter(|p| {
                // Cheap rejection before the rotation: height slab and bounding circle.
                let (ex, ey) = (p[0] - self.x, p[1] - self.y);
                p[2] >= bottom && p[2] <= top && ex * ex + ey * ey <= r2 + 1e-9 && self.contains(*p)
            })
            .count()
    }

    /// The box moved by a rigid transform `b_from_a` (this box given in frame `a`). The centre moves
    /// exactly, sizes are kept and the heading becomes the yaw of the transformed box x axis, so
    /// the result stays upright: for a transform with roll/pitch the box is the upright box around
    /// the same centre whose heading matches the tilted object's direction seen from above.
    pub fn transformed(&self, b_from_a: &Pose) -> Self {
        let c = b_from_a.transform_point(&self.center());
        let (s, co) = self.heading.sin_cos();
        let dir = b_from_a.rotation * Vector3::new(co, s, 0.0);
        let heading = if dir.x.abs() < 1e-12 && dir.y.abs() < 1e-12 {
            // Heading axis became vertical: fall back to the rotation's own yaw.
            self.heading + b_from_a.rotation.euler_angles().2
        } else {
            dir.y.atan2(dir.x)
        };
        Self { x: c.x, y: c.y, z: c.z, heading, ..*self }
    }

    /// Heading wrapped to `[-pi, pi)`.
    pub fn with_wrapped_heading(mut self) -> Self {
        self.heading = wrap_angle(self.heading);
        self
    }

    /// Radius of the BEV circumscribed circle (not `hypot`: libm's correctly rounded one was
    /// the largest single cost of rotated NMS; box sizes cannot overflow the squares).
    pub fn bev_radius(&self) -> f64 {
        0.5 * (self.dx * self.dx + self.dy * self.dy).sqrt()
    }
}

/// Wraps an angle to `[-pi, pi)`.
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let w = (a + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    if w >= std::f64::consts::PI {
        w - two_pi
    } else {
        w
    }
}

impl From<[f64; 7]> for Box3d {
    fn from(a: [f64; 7]) -> Self {
        Self::from_array(a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::PoseExt;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn corners_follow_openpcdet_order() {
        let b = Box3d::new(1.0, 2.0, 3.0, 4.0, 2.0, 1.0, 0.0);
        let c = b.corners();
        assert_eq!(c[0], Point3::new(3.0, 3.0, 2.5));
        assert_eq!(c[2], Point3::new(-1.0, 1.0, 2.5));
        assert_eq!(c[6], Point3::new(-1.0, 1.0, 3.5));
        let r = Box3d { heading: FRAC_PI_2, ..b }.corners();
        assert!((r[0] - Point3::new(0.0, 4.0, 2.5)).norm() < 1e-12);
    }

    #[test]
    fn inside_is_inclusive() {
        let b = Box3d::new(0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0);
        assert!(b.contains([1.0, 1.0, 1.0]));
        assert!(!b.contains([1.0 + 1e-9, 0.0, 0.0]));
        let pts = [[0.0, 0.0, 0.0], [1.0, -1.0, -1.0], [0.0, 0.0, 1.5], [5.0, 0.0, 0.0]];
        assert_eq!(b.count_points(pts), 2);
    }

    #[test]
    fn rotated_inside_test() {
        let b = Box3d::new(10.0, 5.0, 0.0, 4.0, 1.0, 2.0, FRAC_PI_2);
        assert!(b.contains([10.0, 6.9, 0.0]));
        assert!(!b.contains([11.9, 5.0, 0.0]));
    }

    #[test]
    fn transform_keeps_size_and_moves_heading() {
        let b = Box3d::new(5.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.3);
        let yaw = Pose::from_xyz_rpy([1.0, 2.0, 3.0], 0.0, 0.0, 0.5);
        let t = b.transformed(&yaw);
        assert!((t.heading - 0.8).abs() < 1e-12);
        assert_eq!((t.dx, t.dy, t.dz), (4.0, 2.0, 1.5));
        let back = t.transformed(&yaw.inverse());
        for (a, e) in back.to_array().iter().zip(b.to_array()) {
            assert!((a - e).abs() < 1e-12);
        }
        // Roll/pitch leave the heading of a box facing along x unchanged when pitching about y.
        let pitch = Pose::from_xyz_rpy([0.0; 3], 0.0, 0.2, 0.0);
        let p = Box3d { heading: 0.0, ..b }.transformed(&pitch);
        assert!(p.heading.abs() < 1e-12);
        assert!((p.z - (-5.0 * 0.2f64.sin())).abs() < 1e-12);
    }

    #[test]
    fn wrap() {
        assert!((wrap_angle(3.0 * std::f64::consts::PI) + std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-15);
        assert!(wrap_angle(std::f64::consts::PI) < std::f64::consts::PI);
    }

    #[test]
    fn rejects_bad_arrays() {
        assert!(Box3d::try_from_array([f64::NAN, 0., 0., 1., 1., 1., 0.]).is_err());
        assert!(Box3d::try_from_array([0., 0., 0., -1., 1., 1., 0.]).is_err());
        assert!(Box3d::try_from_array([0., 0., 0., 1., 1., 1., 0.]).is_ok());
    }
}
