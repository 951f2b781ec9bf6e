//! The ground right around one box, and whether a dataset's labels stand on it.
//!
//! Ground-truth paste-in (`gt_sampling`) sets pasted objects on the local ground of the receiving
//! frame; the label check measures how far labelled boxes' bottoms sit above the ground around
//! them. A converter that writes a box's centre where the KITTI format expects its bottom centre
//! (a known bug of a public Argoverse → KITTI adapter) leaves every box floating half its height
//! above the ground: the detector can be right and score no 3D AP at all. Such a shift cannot be
//! seen in a table of AP, only against the points.

use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};

/// How the local ground under a box is found: the `quantile` of the z of the frame's points
/// within `margin_m` of the box's footprint (outside it: the points inside belong to whatever
/// stands there); with fewer than `min_points` there the margin is doubled once.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LocalGround {
    pub margin_m: f64,
    pub quantile: f64,
    pub min_points: usize,
}

impl Default for LocalGround {
    fn default() -> Self {
        Self { margin_m: 2.0, quantile: 0.1, min_points: 8 }
    }
}

impl LocalGround {
    /// The ground height under `b`; `None` when too few points are near (far away, or nothing
    /// but sky).
    pub fn z(&self, points: &[[f32; 4]], b: &Box3d) -> Option<f64> {
        let r = b.bev_radius();
        let footprint = Box3d { z: 0.0, dz: f64::MAX, ..*b };
        for margin in [self.margin_m, 2.0 * self.margin_m] {
            let reach = r + margin;
            let mut zs: Vec<f32> = points
                .iter()
                .filter(|p| {
                    let (ex, ey) = (p[0] as f64 - b.x, p[1] as f64 - b.y);
                    ex * ex + ey * ey <= reach * reach && !footprint.contains([p[0] as f64, p[1] as f64, 0.0])
                })
                .map(|p| p[2])
                .collect();
            if zs.len() >= self.min_points.max(1) {
                let k = ((zs.len() - 1) as f64 * self.quantile.clamp(0.0, 1.0)).round() as usize;
                let (_, z, _) = zs.select_nth_unstable_by(k, f32::total_cmp);
                return Some(*z as f64);
            }
        }
        None
    }
}

/// Box bottoms against the ground around them, over the labelled boxes of some frames.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LabelGroundCheck {
    /// Bottom minus local ground (m) of each box whose ground was found.
    pub offsets_m: Vec<f64>,
    /// The height (m) of those boxes, in the same order.
    pub heights_m: Vec<f64>,
    /// Boxes left out: no ground near them, or beyond the check's range.
    pub skipped: usize,
}

impl LabelGroundCheck {
    /// Labels further than this from the sensor are left out: their ground is a few sparse rings.
    pub const MAX_RANGE_M: f64 = 40.0;
    /// A median offset beyond this (m) says the labels do not stand on the ground. Tight real
    /// labels (KITTI's) and the simulator's sit within a decimetre or two of it.
    pub const FLOATING_M: f64 = 0.3;
    /// Fewer checked boxes than this say nothing.
    pub const MIN_BOXES: usize = 5;

    /// Adds one frame's labelled boxes.
    pub fn add_frame<'a>(
        &mut self,
        points: &[[f32; 4]],
        boxes: impl IntoIterator<Item = &'a Box3d>,
        ground: &LocalGround,
    ) {
        for b in boxes {
            if b.x.hypot(b.y) > Self::MAX_RANGE_M {
                self.skipped += 1;
                continue;
            }
            match ground.z(points, b) {
                Some(z) => {
                    self.offsets_m.push(b.bottom() - z);
                    self.heights_m.push(b.dz);
                }
                None => self.skipped += 1,
            }
        }
    }

    pub fn merge(&mut self, other: &LabelGroundCheck) {
        self.offsets_m.extend_from_slice(&other.offsets_m);
        self.heights_m.extend_from_slice(&other.heights_m);
        self.skipped += other.skipped;
    }

    /// The median offset (m), `None` with fewer than [`Self::MIN_BOXES`] boxes checked.
    pub fn median_m(&self) -> Option<f64> {
        median(self.offsets_m.clone())
    }

    /// The median offset (m) were each label's location its box's centre rather than its bottom
    /// centre (each box half its height lower).
    pub fn median_as_centres_m(&self) -> Option<f64> {
        median(self.offsets_m.iter().zip(&self.heights_m).map(|(o, h)| o - 0.5 * h).collect())
    }

    /// Floating labels that stand on the ground once their locations are read as box centres:
    /// the converter's mistake named, so the labels can be read right.
    pub fn reads_as_centres(&self) -> bool {
        self.floating() && self.median_as_centres_m().is_some_and(|m| m.abs() <= Self::FLOATING_M)
    }

    /// Whether the labels float above (or sink below) the ground by more than [`Self::FLOATING_M`].
    pub fn floating(&self) -> bool {
        self.median_m().is_some_and(|m| m.abs() > Self::FLOATING_M)
    }
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.len() < LabelGroundCheck::MIN_BOXES {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Flat ground at `ground_z` on a 0.25 m grid over ±30 m, and a car standing on it at
    /// (`x`, 0) whose label is lifted by `lift`.
    fn scene(ground_z: f32, x: f64, lift: f64) -> (Vec<[f32; 4]>, Box3d) {
        let mut pts = Vec::new();
        for i in -120..120 {
            for j in -24..24 {
                pts.push([i as f32 * 0.25, j as f32 * 0.25, ground_z, 0.1]);
            }
        }
        let (dx, dy, dz) = (4.0, 1.8, 1.5);
        let b = Box3d::new(x, 0.0, ground_z as f64 + 0.5 * dz + lift, dx, dy, dz, 0.3);
        // The car's own points: inside the footprint, ignored by the ground estimate.
        for k in 0..40 {
            pts.push([x as f32, 0.0, ground_z + 0.05 * k as f32, 0.3]);
        }
        (pts, b)
    }

    #[test]
    fn the_ground_around_a_box_ignores_what_stands_in_it() {
        let (pts, b) = scene(-1.1, 12.0, 0.0);
        assert!((LocalGround::default().z(&pts, &b).unwrap() - -1.1).abs() < 1e-6);
        assert_eq!(LocalGround::default().z(&[], &b), None);
    }

    #[test]
    fn labels_lifted_by_half_their_height_are_floating() {
        let ground = LocalGround::default();
        let mut grounded = LabelGroundCheck::default();
        let mut lifted = LabelGroundCheck::default();
        for (k, x) in [6.0, 10.0, 14.0, 18.0, 22.0, 26.0].into_iter().enumerate() {
            let (pts, b) = scene(-1.7 + 0.05 * k as f32, x, 0.0);
            grounded.add_frame(&pts, [&b], &ground);
            // A centre written where the bottom belongs: the box rises by half its height.
            let (pts, b) = scene(-1.7 + 0.05 * k as f32, x, 0.75);
            lifted.add_frame(&pts, [&b], &ground);
        }
        assert!(grounded.median_m().unwrap().abs() < 1e-6 && !grounded.floating() && !grounded.reads_as_centres());
        assert!((lifted.median_m().unwrap() - 0.75).abs() < 1e-6 && lifted.floating());
        assert!(lifted.median_as_centres_m().unwrap().abs() < 1e-6 && lifted.reads_as_centres());
        // Floating by a whole height: not the centre-for-bottom mistake.
        let mut high = LabelGroundCheck::default();
        for x in [6.0, 10.0, 14.0, 18.0, 22.0] {
            let (pts, b) = scene(-1.7, x, 1.5);
            high.add_frame(&pts, [&b], &ground);
        }
        assert!(high.floating() && !high.reads_as_centres());
        // Too few boxes say nothing; far boxes are skipped.
        let mut few = LabelGroundCheck::default();
        let (pts, b) = scene(-1.7, 10.0, 0.75);
        let far = Box3d { x: 60.0, ..b };
        few.add_frame(&pts, [&b, &far], &ground);
        assert_eq!((few.offsets_m.len(), few.skipped, few.median_m(), few.floating()), (1, 1, None, false));
    }
}
