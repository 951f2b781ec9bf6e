//! Exact area of the intersection of two convex quadrilaterals (Sutherland–Hodgman clipping in
//! f64 on fixed-size buffers, so pairwise IoU matrices allocate nothing per pair).

/// Clipping a quad by 4 half-planes adds at most one vertex per plane.
const MAX_VERTICES: usize = 12;

#[derive(Clone, Copy)]
struct Poly {
    v: [[f64; 2]; MAX_VERTICES],
    n: usize,
}

impl Poly {
    fn from_quad(q: &[[f64; 2]; 4]) -> Self {
        let mut v = [[0.0; 2]; MAX_VERTICES];
        v[..4].copy_from_slice(q);
        Self { v, n: 4 }
    }

    fn push(&mut self, p: [f64; 2]) {
        if self.n < MAX_VERTICES {
            self.v[self.n] = p;
            self.n += 1;
        }
    }
}

/// Signed area (shoelace); positive for counter-clockwise.
pub fn signed_area(pts: &[[f64; 2]]) -> f64 {
    let n = pts.len();
    if n < 3 {
        return 0.0;
    }
    let mut s = 0.0;
    for i in 0..n {
        let (a, b) = (pts[i], pts[(i + 1) % n]);
        s += a[0] * b[1] - a[1] * b[0];
    }
    0.5 * s
}

/// Area of `subject ∩ clip` for two convex quads given counter-clockwise. Touching or disjoint
/// quads give 0, degenerate (zero-size) quads give 0; never NaN for finite input.
pub fn quad_intersection_area(subject: &[[f64; 2]; 4], clip: &[[f64; 2]; 4]) -> f64 {
    let mut poly = Poly::from_quad(subject);
    // Tolerance scaled to the coordinates so that points on a shared edge count as inside.
    let scale = subject.iter().chain(clip.iter()).fold(1.0f64, |m, p| m.max(p[0].abs()).max(p[1].abs()));
    let eps = 1e-12 * scale * scale;
    for i in 0..4 {
        let (a, b) = (clip[i], clip[(i + 1) % 4]);
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        if ex == 0.0 && ey == 0.0 {
            continue; // zero-length edge of a degenerate box: no half-plane
        }
        let side = |p: [f64; 2]| ex * (p[1] - a[1]) - ey * (p[0] - a[0]);
        let mut out = Poly { v: [[0.0; 2]; MAX_VERTICES], n: 0 };
        for k in 0..poly.n {
            let (p, q) = (poly.v[k], poly.v[(k + 1) % poly.n]);
            let (dp, dq) = (side(p), side(q));
            let (p_in, q_in) = (dp >= -eps, dq >= -eps);
            if p_in {
                out.push(p);
            }
            if p_in != q_in && (dp - dq).abs() > 0.0 {
                let t = (dp / (dp - dq)).clamp(0.0, 1.0);
                out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
            }
        }
        poly = out;
        if poly.n < 3 {
            return 0.0;
        }
    }
    signed_area(&poly.v[..poly.n]).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x: f64, y: f64, s: f64) -> [[f64; 2]; 4] {
        [[x, y], [x + s, y], [x + s, y + s], [x, y + s]]
    }

    #[test]
    fn overlapping_squares() {
        let a = square(0.0, 0.0, 2.0);
        let b = square(1.0, 1.0, 2.0);
        assert!((quad_intersection_area(&a, &b) - 1.0).abs() < 1e-12);
        assert!((quad_intersection_area(&b, &a) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn touching_and_disjoint() {
        let a = square(0.0, 0.0, 1.0);
        assert_eq!(quad_intersection_area(&a, &square(1.0, 0.0, 1.0)), 0.0);
        assert_eq!(quad_intersection_area(&a, &square(1.0, 1.0, 1.0)), 0.0);
        assert_eq!(quad_intersection_area(&a, &square(5.0, 5.0, 1.0)), 0.0);
    }

    #[test]
    fn identical_and_degenerate() {
        let a = square(3.0, -7.0, 1.5);
        assert!((quad_intersection_area(&a, &a) - 2.25).abs() < 1e-12);
        let flat = [[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 0.0]];
        let r = quad_intersection_area(&flat, &a);
        assert!(r.is_finite() && r == 0.0);
        let r = quad_intersection_area(&square(0.0, 0.0, 1.0), &flat);
        assert!(r.is_finite() && r.abs() < 1e-12);
    }
}
