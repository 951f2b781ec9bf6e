//! Generalised IoU of two boxes in bird's-eye view (rotated rectangles): IoU minus the share of
//! the smallest enclosing convex region (the hull of both boxes' corners) that neither covers.
//! In [−1, 1]; unlike IoU it still ranks boxes that do not overlap by how far apart they are,
//! which is what lets a fast or badly predicted track associate (SimpleTrack's `giou`).

use pi3det_geometry::iou::bev_intersection;
use pi3det_geometry::polygon::signed_area;
use pi3det_geometry::Box3d;

pub fn bev_giou(a: &Box3d, b: &Box3d) -> f64 {
    let inter = bev_intersection(a, b);
    let union = a.dx * a.dy + b.dx * b.dy - inter;
    let mut corners: Vec<[f64; 2]> = a.bev_corners().into_iter().chain(b.bev_corners()).collect();
    let hull = convex_hull(&mut corners);
    let enclosing = signed_area(&hull).abs();
    if union <= 0.0 || enclosing <= 0.0 {
        return 0.0;
    }
    inter / union - (enclosing - union) / enclosing
}

/// Andrew's monotone chain; counter-clockwise, without repeated end point.
fn convex_hull(pts: &mut [[f64; 2]]) -> Vec<[f64; 2]> {
    pts.sort_by(|p, q| p[0].total_cmp(&q[0]).then(p[1].total_cmp(&q[1])));
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(pts.len() * 2);
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> =
            if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(x: f64, y: f64) -> Box3d {
        Box3d { x, y, z: 0.0, dx: 1.0, dy: 1.0, dz: 1.0, heading: 0.0 }
    }

    #[test]
    fn giou_by_hand() {
        assert!((bev_giou(&unit(0.0, 0.0), &unit(0.0, 0.0)) - 1.0).abs() < 1e-12);
        // Half overlap: IoU 0.5/1.5, hull 1.5 → GIoU = 1/3.
        assert!((bev_giou(&unit(0.0, 0.0), &unit(0.5, 0.0)) - 1.0 / 3.0).abs() < 1e-12);
        // 1 m gap: IoU 0, hull 3×1 = 3, union 2 → −1/3.
        assert!((bev_giou(&unit(0.0, 0.0), &unit(2.0, 0.0)) + 1.0 / 3.0).abs() < 1e-12);
        // Corner to corner: the hull is a hexagon of area 4 − 2·½ = 3, the union 2.
        let g = bev_giou(&unit(0.0, 0.0), &unit(1.0, 1.0));
        assert!((g + 1.0 / 3.0).abs() < 1e-12, "{g}");
        let rotated = Box3d { heading: std::f64::consts::FRAC_PI_4, ..unit(0.0, 0.0) };
        let g = bev_giou(&unit(0.0, 0.0), &rotated);
        assert!(g > 0.5 && g < 1.0);
    }
}
