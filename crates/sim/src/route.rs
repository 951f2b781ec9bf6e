//! Planar paths parameterised by arc length: what platforms and moving actors follow.

/// A pose on a route: position, heading (rad, counter-clockwise from +x) and signed curvature
/// (1/m, positive turning left).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RouteSample {
    pub xy: [f64; 2],
    pub heading_rad: f64,
    pub curvature_per_m: f64,
}

/// A polyline with cumulative arc length. Sampling beyond either end extrapolates along the end
/// segment, so an actor that outlives its route keeps going straight instead of stopping.
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    points: Vec<[f64; 2]>,
    cumulative_m: Vec<f64>,
}

impl Route {
    /// From at least two distinct points; repeated points are dropped.
    pub fn new(points: Vec<[f64; 2]>) -> Self {
        let mut pts: Vec<[f64; 2]> = Vec::with_capacity(points.len());
        for p in points {
            if pts.last().is_none_or(|q: &[f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) > 1e-9) {
                pts.push(p);
            }
        }
        assert!(pts.len() >= 2, "a route needs two distinct points");
        let mut cumulative_m = Vec::with_capacity(pts.len());
        let mut s = 0.0;
        cumulative_m.push(0.0);
        for w in pts.windows(2) {
            s += (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            cumulative_m.push(s);
        }
        Self { points: pts, cumulative_m }
    }

    /// A straight route from `a` to `b`.
    pub fn straight(a: [f64; 2], b: [f64; 2]) -> Self {
        Self::new(vec![a, b])
    }

    /// Through `corners`, each interior corner replaced by a quadratic Bézier blend of about
    /// `radius_m` (shrunk where segments are short), sampled every `step_m`.
    pub fn rounded(corners: &[[f64; 2]], radius_m: f64, step_m: f64) -> Self {
        if corners.len() < 3 {
            return Self::new(corners.to_vec());
        }
        let mut pts = vec![corners[0]];
        for i in 1..corners.len() - 1 {
            let (a, p, b) = (corners[i - 1], corners[i], corners[i + 1]);
            let len_in = (p[0] - a[0]).hypot(p[1] - a[1]);
            let len_out = (b[0] - p[0]).hypot(b[1] - p[1]);
            let d = radius_m.min(0.45 * len_in).min(0.45 * len_out);
            if d < 1e-6 || len_in < 1e-9 || len_out < 1e-9 {
                pts.push(p);
                continue;
            }
            let s = [p[0] - (p[0] - a[0]) / len_in * d, p[1] - (p[1] - a[1]) / len_in * d];
            let e = [p[0] + (b[0] - p[0]) / len_out * d, p[1] + (b[1] - p[1]) / len_out * d];
            let n = ((2.0 * d / step_m).ceil() as usize).max(2);
            for k in 0..=n {
                let u = k as f64 / n as f64;
                let (w0, w1, w2) = ((1.0 - u) * (1.0 - u), 2.0 * u * (1.0 - u), u * u);
                pts.push([w0 * s[0] + w1 * p[0] + w2 * e[0], w0 * s[1] + w1 * p[1] + w2 * e[1]]);
            }
        }
        pts.push(corners[corners.len() - 1]);
        Self::new(pts)
    }

    pub fn length_m(&self) -> f64 {
        *self.cumulative_m.last().unwrap_or(&0.0)
    }

    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// Segment index containing arc length `s` (clamped to the end segments).
    fn segment(&self, s: f64) -> usize {
        let n = self.points.len() - 1;
        match self.cumulative_m.binary_search_by(|c| c.partial_cmp(&s).unwrap_or(std::cmp::Ordering::Less)) {
            Ok(i) => i.min(n - 1),
            Err(i) => i.saturating_sub(1).min(n - 1),
        }
    }

    fn position_heading(&self, s: f64) -> ([f64; 2], f64) {
        let i = self.segment(s);
        let (a, b) = (self.points[i], self.points[i + 1]);
        let len = self.cumulative_m[i + 1] - self.cumulative_m[i];
        let u = (s - self.cumulative_m[i]) / len;
        let heading = (b[1] - a[1]).atan2(b[0] - a[0]);
        ([a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])], heading)
    }

    /// Position, heading and curvature at arc length `s`. Heading is smoothed over ±1 m so the
    /// polyline's kinks do not show up as yaw steps.
    pub fn sample(&self, s: f64) -> RouteSample {
        let (xy, _) = self.position_heading(s);
        let h = 1.0;
        let (p0, _) = self.position_heading(s - h);
        let (p1, _) = self.position_heading(s + h);
        let heading_rad = (p1[1] - p0[1]).atan2(p1[0] - p0[0]);
        let (_, ha) = self.position_heading(s - h);
        let (_, hb) = self.position_heading(s + h);
        let dh = pi3det_geometry::boxes::wrap_angle(hb - ha);
        RouteSample { xy, heading_rad, curvature_per_m: dh / (2.0 * h) }
    }

    /// Axis-aligned bounds `[xmin, ymin, xmax, ymax]`.
    pub fn bounds(&self) -> [f64; 4] {
        let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        for p in &self.points {
            b = [b[0].min(p[0]), b[1].min(p[1]), b[2].max(p[0]), b[3].max(p[1])];
        }
        b
    }

    /// Distance from `p` to the route (for keeping scenery off a platform's path).
    pub fn distance_to(&self, p: [f64; 2]) -> f64 {
        self.points
            .windows(2)
            .map(|w| {
                let (a, b) = (w[0], w[1]);
                let (vx, vy) = (b[0] - a[0], b[1] - a[1]);
                let len2 = vx * vx + vy * vy;
                let u = (((p[0] - a[0]) * vx + (p[1] - a[1]) * vy) / len2).clamp(0.0, 1.0);
                (p[0] - a[0] - u * vx).hypot(p[1] - a[1] - u * vy)
            })
            .fold(f64::INFINITY, f64::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn straight_route_samples_and_extrapolates() {
        let r = Route::straight([0.0, 0.0], [10.0, 0.0]);
        assert_eq!(r.length_m(), 10.0);
        let s = r.sample(4.0);
        assert!((s.xy[0] - 4.0).abs() < 1e-12 && s.heading_rad.abs() < 1e-12);
        assert!((r.sample(15.0).xy[0] - 15.0).abs() < 1e-12);
        assert!((r.sample(-2.0).xy[0] + 2.0).abs() < 1e-12);
    }

    #[test]
    fn rounded_corner_turns_left_smoothly() {
        let r = Route::rounded(&[[0.0, 0.0], [20.0, 0.0], [20.0, 20.0]], 6.0, 0.5);
        let end = r.sample(r.length_m() - 0.5);
        assert!((end.heading_rad - FRAC_PI_2).abs() < 1e-6);
        let mid = r.sample(20.0);
        assert!(mid.curvature_per_m > 0.05, "{mid:?}");
        assert!(r.distance_to([20.0, 10.0]) < 1e-9);
        assert!(r.length_m() < 40.0);
    }
}
