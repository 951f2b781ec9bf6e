//! A box's 12 edges in one camera: clipped against the near plane in camera coordinates before
//! projecting (a box straddling the camera plane keeps its visible part, with finite pixels),
//! subdivided when the camera distorts so that straight edges bend as they do in the image.

use nalgebra::Vector3;
use pi3det_geometry::Box3d;

use super::camera::{CameraModel, NEAR};

/// Corner pairs of [`Box3d::corners`]: bottom face, top face, verticals.
pub const EDGES: [(usize, usize); 12] =
    [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)];

/// Pieces per edge on distorting cameras.
const SUBDIVISIONS: usize = 16;

/// The part of segment `a`–`b` (camera coordinates) with `z ≥ NEAR`.
pub fn clip_near(a: Vector3<f64>, b: Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let cut = |inside: Vector3<f64>, outside: Vector3<f64>| {
        let t = (NEAR - inside.z) / (outside.z - inside.z);
        let mut p = inside + (outside - inside) * t;
        p.z = NEAR; // exact, so rounding cannot push it behind the plane
        p
    };
    match (a.z >= NEAR, b.z >= NEAR) {
        (true, true) => Some((a, b)),
        (true, false) => Some((a, cut(a, b))),
        (false, true) => Some((cut(b, a), b)),
        (false, false) => None,
    }
}

/// How one box looks from one camera.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxView {
    /// Every corner is behind the near plane.
    pub behind: bool,
    /// Pixel polylines of the visible parts of the edges (not clipped to the image).
    pub polylines: Vec<Vec<[f64; 2]>>,
}

impl BoxView {
    /// Whether any drawn segment crosses the `width × height` image.
    pub fn in_image(&self, width: u32, height: u32) -> bool {
        self.segments().any(|(a, b)| clip_to_rect(a, b, width as f64, height as f64).is_some())
    }

    /// The pixels the visible edges cover inside the image, `[x0, y0, x1, y1]`.
    pub fn image_bbox(&self, width: u32, height: u32) -> Option<[f64; 4]> {
        let (w, h) = (width as f64, height as f64);
        let mut r: Option<[f64; 4]> = None;
        for (a, b) in self.segments().filter_map(|(a, b)| clip_to_rect(a, b, w, h)) {
            for p in [a, b] {
                let q = r.get_or_insert([p[0], p[1], p[0], p[1]]);
                *q = [q[0].min(p[0]), q[1].min(p[1]), q[2].max(p[0]), q[3].max(p[1])];
            }
        }
        r
    }

    pub fn segments(&self) -> impl Iterator<Item = ([f64; 2], [f64; 2])> + '_ {
        self.polylines.iter().flat_map(|l| l.windows(2).map(|w| (w[0], w[1])))
    }
}

/// Projects a LiDAR-frame box into a camera.
pub fn view_box(cam: &CameraModel, b: &Box3d) -> BoxView {
    let corners = b.corners().map(|c| cam.to_camera([c.x, c.y, c.z]));
    let behind = corners.iter().all(|c| c.z.is_nan() || c.z < NEAR);
    let pieces = if cam.has_distortion() { SUBDIVISIONS } else { 1 };
    let mut polylines = Vec::new();
    for (i, j) in EDGES {
        let Some((a, b)) = clip_near(corners[i], corners[j]) else { continue };
        // Points the model cannot project (beyond its valid radius) split the edge.
        let mut line = Vec::new();
        for k in 0..=pieces {
            let p = a + (b - a) * (k as f64 / pieces as f64);
            match cam.camera_to_pixel(p) {
                Some(px) => line.push(px),
                None if line.len() >= 2 => polylines.push(std::mem::take(&mut line)),
                None => line.clear(),
            }
        }
        if line.len() >= 2 {
            polylines.push(line);
        }
    }
    BoxView { behind, polylines }
}

/// Liang–Barsky: the part of segment `a`–`b` inside `[0, w] × [0, h]`.
pub fn clip_to_rect(a: [f64; 2], b: [f64; 2], w: f64, h: f64) -> Option<([f64; 2], [f64; 2])> {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a[0]), (dx, w - a[0]), (-dy, a[1]), (dy, h - a[1])] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    (t0 <= t1).then(|| ([a[0] + t0 * dx, a[1] + t0 * dy], [a[0] + t1 * dx, a[1] + t1 * dy]))
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Matrix4};

    use super::*;

    /// A camera looking along LiDAR +x (camera x = −y, y = −z, z = x).
    fn forward_camera() -> CameraModel {
        let e = Matrix4::new(0., -1., 0., 0., 0., 0., -1., 0., 1., 0., 0., 0., 0., 0., 0., 1.);
        let k = Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0);
        CameraModel::new("front", e, k, &[])
    }

    #[test]
    fn straddling_box_is_clipped_to_finite_pixels() {
        // Centre at the camera: half of it is behind the camera plane.
        let v = view_box(&forward_camera(), &Box3d::new(0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.3));
        assert!(!v.behind);
        assert!(!v.polylines.is_empty());
        for p in v.polylines.iter().flatten() {
            assert!(p[0].is_finite() && p[1].is_finite(), "{p:?}");
        }
        // 4 edges along the box's length cross the plane, 4 faces' edges lie in front.
        assert_eq!(v.polylines.len(), 8);
    }

    #[test]
    fn box_behind_is_flagged_and_not_drawn() {
        let v = view_box(&forward_camera(), &Box3d::new(-10.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0));
        assert!(v.behind && v.polylines.is_empty());
        assert!(!v.in_image(640, 480));
    }

    #[test]
    fn box_in_front_is_in_the_image_and_one_far_left_is_not() {
        let cam = forward_camera();
        assert!(view_box(&cam, &Box3d::new(10.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0)).in_image(640, 480));
        let side = view_box(&cam, &Box3d::new(1.0, 20.0, 0.0, 1.0, 1.0, 1.0, 0.0));
        assert!(!side.behind && !side.in_image(640, 480));
    }

    #[test]
    fn liang_barsky() {
        assert_eq!(clip_to_rect([-10.0, 5.0], [20.0, 5.0], 10.0, 10.0), Some(([0.0, 5.0], [10.0, 5.0])));
        assert_eq!(clip_to_rect([-10.0, -5.0], [-1.0, 20.0], 10.0, 10.0), None);
        assert_eq!(clip_to_rect([1.0, 1.0], [2.0, 2.0], 10.0, 10.0), Some(([1.0, 1.0], [2.0, 2.0])));
    }
}
