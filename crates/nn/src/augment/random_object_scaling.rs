//! Random Object Scaling (ST3D, Yang et al. 2021, §3.1): each box and the points inside it are
//! scaled about the box's bottom centre by a factor from `range` (U(0.75, 1.0) in ST3D), so a
//! detector trained on large source objects also fires on smaller target ones. A scale whose
//! box would overlap another box in BEV is drawn again, up to `max_tries` times, and the box is
//! left as it is when none fits. Points are scaled in the box frame (length, width and height
//! alike); background points that fall into a grown box are removed so box and points agree.

use pi3det_geometry::iou::bev_intersection;
use pi3det_geometry::Box3d;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{points_in_box, Augment, Sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RandomObjectScalingConfig {
    /// Scale factors are drawn uniformly from `[range[0], range[1])`.
    pub range: [f64; 2],
    /// Draws per box before it is left unscaled.
    pub max_tries: usize,
}

impl Default for RandomObjectScalingConfig {
    fn default() -> Self {
        Self { range: [0.75, 1.0], max_tries: 50 }
    }
}

pub struct RandomObjectScaling(pub RandomObjectScalingConfig);

/// `b` scaled by `f` about its bottom centre.
pub fn scaled_box(b: &Box3d, f: f64) -> Box3d {
    let bottom = b.bottom();
    Box3d { dx: b.dx * f, dy: b.dy * f, dz: b.dz * f, z: bottom + 0.5 * b.dz * f, ..*b }
}

/// Moves the points of `b` to where they are in `to` (same centre on the ground and heading,
/// other sizes): each box-frame coordinate scaled by the size ratio, heights from the bottom.
/// Background points inside `to` that were not in `b` are removed.
pub(crate) fn resize_object(points: &mut Vec<[f32; 4]>, b: &Box3d, to: &Box3d) {
    let inside = points_in_box(points, b);
    let (sn, c) = b.heading.sin_cos();
    let (rx, ry, rz) = (to.dx / b.dx, to.dy / b.dy, to.dz / b.dz);
    let (b0, t0) = (b.bottom(), to.bottom());
    for &i in &inside {
        let p = &mut points[i];
        let (x, y) = (p[0] as f64 - b.x, p[1] as f64 - b.y);
        // Into the box frame, scaled, and back.
        let (u, v) = (c * x + sn * y, -sn * x + c * y);
        let (u, v) = (u * rx, v * ry);
        p[0] = (to.x + c * u - sn * v) as f32;
        p[1] = (to.y + sn * u + c * v) as f32;
        p[2] = (t0 + (p[2] as f64 - b0) * rz) as f32;
    }
    let mut keep = vec![true; points.len()];
    for i in points_in_box(points, to) {
        keep[i] = false;
    }
    for &i in &inside {
        keep[i] = true;
    }
    let mut k = 0;
    points.retain(|_| {
        k += 1;
        keep[k - 1]
    });
}

impl Augment for RandomObjectScaling {
    fn name(&self) -> &'static str {
        "random_object_scaling"
    }

    fn apply(&self, s: &mut Sample, rng: &mut ChaCha8Rng) {
        let [lo, hi] = self.0.range;
        for k in 0..s.boxes.len() {
            let b = s.boxes[k];
            let others: Vec<Box3d> = s
                .boxes
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != k)
                .map(|(_, o)| *o)
                .chain(s.ignored.iter().copied())
                .collect();
            let fits = |c: &Box3d| others.iter().all(|o| bev_intersection(c, o) <= 0.0);
            let mut chosen = None;
            for _ in 0..self.0.max_tries {
                let f = if hi > lo { rng.random_range(lo..hi) } else { lo };
                let c = scaled_box(&b, f);
                if fits(&c) {
                    chosen = Some(c);
                    break;
                }
            }
            if let Some(c) = chosen {
                resize_object(&mut s.points, &b, &c);
                s.boxes[k] = c;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::*;
    use super::*;

    #[test]
    fn objects_shrink_with_their_points() {
        let s0 = sample();
        let mut s = s0.clone();
        RandomObjectScaling(RandomObjectScalingConfig { range: [0.8, 0.9], max_tries: 50 }).apply(&mut s, &mut rng(3));
        assert_eq!(s.points.len(), s0.points.len(), "shrinking removes nothing");
        for (a, b) in s.boxes.iter().zip(&s0.boxes) {
            let f = a.dx / b.dx;
            assert!((0.8..0.9).contains(&f), "{f}");
            assert!((a.dy / b.dy - f).abs() < 1e-12 && (a.dz / b.dz - f).abs() < 1e-12);
            assert!((a.bottom() - b.bottom()).abs() < 1e-12, "stays on the ground");
            assert_eq!((a.x, a.y, a.heading), (b.x, b.y, b.heading));
            // Every point of the old box is inside the new one, at the scaled box-frame offset.
            let (old, new) = (points_in_box(&s0.points, b), points_in_box(&s.points, a));
            assert_eq!(old, new);
            for &i in &old {
                let (p, q) = (s0.points[i], s.points[i]);
                let (sn, c) = b.heading.sin_cos();
                let u0 = c * (p[0] as f64 - b.x) + sn * (p[1] as f64 - b.y);
                let u1 = c * (q[0] as f64 - a.x) + sn * (q[1] as f64 - a.y);
                assert!((u1 - f * u0).abs() < 1e-4, "{u0} {u1}");
                assert!(((q[2] as f64 - a.bottom()) - f * (p[2] as f64 - b.bottom())).abs() < 1e-4);
            }
        }
    }

    /// A scale that would make two boxes overlap in BEV is drawn again; none fitting leaves the box.
    #[test]
    fn overlapping_scales_are_rejected() {
        let a = Box3d::new(0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0);
        let b = Box3d::new(4.2, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0);
        let mut s = Sample { boxes: vec![a, b], classes: vec![0, 0], ..Default::default() };
        s.points = vec![[0.5, 0.2, 0.1, 0.0], [4.0, 0.1, 0.0, 0.0]];
        // Growing by 1.1–1.2 makes a reach 2.2–2.4 m forward, into b (from 2.2 m): always rejected.
        let grow = RandomObjectScaling(RandomObjectScalingConfig { range: [1.1, 1.2], max_tries: 50 });
        let s0 = s.clone();
        grow.apply(&mut s, &mut rng(1));
        assert_eq!(s.boxes, s0.boxes);
        assert_eq!(s.points, s0.points);
        // With room to grow, a grown box swallows a background point, which is removed.
        let mut s = Sample { boxes: vec![a], classes: vec![0], ..Default::default() };
        s.points = vec![[0.5, 0.2, 0.1, 0.0], [2.1, 0.0, 0.0, 0.0]];
        RandomObjectScaling(RandomObjectScalingConfig { range: [1.1, 1.2], max_tries: 5 }).apply(&mut s, &mut rng(1));
        assert_eq!(s.points.len(), 1, "{:?}", s.points);
        assert!(s.boxes[0].dx > 4.4);
    }
}
