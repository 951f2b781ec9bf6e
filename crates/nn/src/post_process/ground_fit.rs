//! Vertical box fit to the frame's points, after NMS: each detection's bottom is set on the
//! local ground around its footprint and its top on the highest point inside it.
//!
//! Why: the error breakdown of the two-stage PointPillars (`pi3det detect --eval`) shows that
//! 3D AP@0.7 is lost almost entirely on z and height (with the GT's z and height the 3D AP
//! equals the BEV AP), and the network's z regresses towards the mean ground height: the BEV map
//! has collapsed the height that the points still carry. The ground beside a box and the roof
//! inside it are measured directly, so this fit replaces the regressed vertical extent where the
//! points support it and keeps it where they do not (too few ground points, a ground far from
//! the predicted bottom, nothing above it inside the footprint). Measured:
//! results/2026-12-02-vertical-box-fit.md.
//!
//! Runs in the detector's frame (z up, as the boxes are upright there), on the points the
//! detector saw. Configured as `[post.ground_fit]`; absent, detections are left as the network
//! made them.

use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};

use crate::error::{NnError, Result};

/// `[post.ground_fit]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GroundFitConfig {
    /// Ground points are looked for within this distance of the box's BEV circumcircle, outside
    /// its footprint.
    pub margin_m: f64,
    /// The ground is this quantile of those points' z (low: the ground is the lowest surface).
    pub ground_quantile: f64,
    pub min_ground_points: usize,
    /// A ground further than this from the predicted bottom is taken as something else (a wall,
    /// a neighbour's body, an unseen ground) and the box keeps its bottom.
    pub max_shift_m: f64,
    /// The top is the highest point inside the footprint shrunk by `top_inset_m` (not a
    /// neighbour's), between the ground + `top_min_frac`·height and the predicted top +
    /// `top_reach_m`, when at least `min_top_points` are there.
    pub top_inset_m: f64,
    pub top_min_frac: f64,
    pub top_reach_m: f64,
    pub min_top_points: usize,
    /// The fitted top comes down at most this far below the predicted one. The highest point
    /// bounds a top from below only: real cars' windows let the laser through and a far car's
    /// roof goes unseen, so missing high points are no evidence of a low roof.
    pub top_max_lower_m: f64,
    /// A fitted height below this fraction of the predicted one is rejected (the fit keeps the box).
    pub min_height_frac: f64,
}

impl Default for GroundFitConfig {
    fn default() -> Self {
        // Chosen on one seed's vehicle val split (360 frames): results/2026-12-02-vertical-box-fit.md.
        Self {
            margin_m: 2.0,
            ground_quantile: 0.05,
            min_ground_points: 8,
            max_shift_m: 1.0,
            top_inset_m: 0.1,
            top_min_frac: 0.3,
            top_reach_m: 0.5,
            min_top_points: 10,
            top_max_lower_m: 0.1,
            min_height_frac: 0.5,
        }
    }
}

impl GroundFitConfig {
    pub fn validate(&self) -> Result<()> {
        let lengths = [self.margin_m, self.max_shift_m, self.top_inset_m, self.top_reach_m, self.top_max_lower_m];
        let fracs = [self.ground_quantile, self.top_min_frac, self.min_height_frac];
        if lengths.iter().any(|v| !(v.is_finite() && *v >= 0.0)) || self.margin_m <= 0.0 {
            return Err(NnError::config("post.ground_fit", "post.ground_fit: margin_m must be positive; max_shift_m, top_inset_m, top_reach_m and top_max_lower_m finite and ≥ 0"));
        }
        if fracs.iter().any(|v| !(0.0..=1.0).contains(v)) {
            return Err(NnError::config(
                "post.ground_fit",
                "post.ground_fit: ground_quantile, top_min_frac and min_height_frac must be in [0, 1]",
            ));
        }
        if self.min_ground_points == 0 {
            return Err(NnError::config("post.ground_fit", "post.ground_fit: min_ground_points must be at least 1"));
        }
        Ok(())
    }
}

/// A frame's points bucketed into square BEV cells (CSR layout), for radius queries.
#[derive(Debug, Clone)]
pub struct PointIndex {
    cell_m: f64,
    origin: [f64; 2],
    nx: usize,
    ny: usize,
    /// `[nx·ny + 1]` start of each cell's points in `points`.
    starts: Vec<u32>,
    /// `(x, y, z)` sorted by cell.
    points: Vec<[f32; 3]>,
}

impl PointIndex {
    /// Cells of `cell_m`; the grid covers the points' bounds, with cells grown when it would
    /// exceed 4M cells. Non-finite points are skipped.
    pub fn new(points: &[[f32; 4]], cell_m: f64) -> Self {
        const MAX_CELLS: f64 = 4.0e6;
        let finite = |p: &&[f32; 4]| p[0].is_finite() && p[1].is_finite() && p[2].is_finite();
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for p in points.iter().filter(finite) {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a] as f64);
                hi[a] = hi[a].max(p[a] as f64);
            }
        }
        if lo[0] > hi[0] {
            return Self { cell_m, origin: [0.0; 2], nx: 0, ny: 0, starts: vec![0], points: Vec::new() };
        }
        let mut cell_m = cell_m.max(1e-3);
        let extent = [hi[0] - lo[0], hi[1] - lo[1]];
        let cells = |c: f64| ((extent[0] / c).floor() + 1.0) * ((extent[1] / c).floor() + 1.0);
        if cells(cell_m) > MAX_CELLS {
            cell_m = (extent[0] * extent[1] / MAX_CELLS).sqrt().max(cell_m) * 1.01;
        }
        let nx = (extent[0] / cell_m).floor() as usize + 1;
        let ny = (extent[1] / cell_m).floor() as usize + 1;
        let cell_of = |p: &[f32; 4]| {
            let i = (((p[0] as f64 - lo[0]) / cell_m) as usize).min(nx - 1);
            let j = (((p[1] as f64 - lo[1]) / cell_m) as usize).min(ny - 1);
            j * nx + i
        };
        let mut starts = vec![0u32; nx * ny + 1];
        for p in points.iter().filter(finite) {
            starts[cell_of(p) + 1] += 1;
        }
        for k in 1..starts.len() {
            starts[k] += starts[k - 1];
        }
        let mut fill = starts.clone();
        let mut sorted = vec![[0f32; 3]; starts[nx * ny] as usize];
        for p in points.iter().filter(finite) {
            let c = cell_of(p);
            sorted[fill[c] as usize] = [p[0], p[1], p[2]];
            fill[c] += 1;
        }
        Self { cell_m, origin: lo, nx, ny, starts, points: sorted }
    }

    /// Points whose BEV distance to `xy` is at most `r`.
    pub fn within(&self, xy: [f64; 2], r: f64) -> impl Iterator<Item = &[f32; 3]> + '_ {
        // Cells clamped to the grid (a circle beyond it scans edge cells, the distance test
        // drops their points); an empty grid scans nothing.
        let span = |c: f64, o: f64, n: usize| {
            let cell = |v: f64| (((v - o) / self.cell_m).floor().max(0.0) as usize).min(n.saturating_sub(1));
            (cell(c - r), cell(c + r))
        };
        let ((i0, i1), (j0, j1)) = (span(xy[0], self.origin[0], self.nx), span(xy[1], self.origin[1], self.ny));
        let rows = if self.nx == 0 { 0..0 } else { j0..j1 + 1 };
        rows.flat_map(move |j| {
            let row = j * self.nx;
            self.points[self.starts[row + i0] as usize..self.starts[row + i1 + 1] as usize].iter()
        })
        .filter(move |p| {
            let (dx, dy) = (p[0] as f64 - xy[0], p[1] as f64 - xy[1]);
            dx * dx + dy * dy <= r * r
        })
    }
}

/// What the fit did to one box.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FitOutcome {
    /// Bottom on the ground and top on the highest point inside.
    GroundAndTop,
    /// Bottom on the ground, the predicted top kept.
    GroundOnly,
    /// Unchanged: too few points near, or the ground too far from the predicted bottom.
    Kept,
}

/// Fits one box's vertical extent (see the module docs); the BEV footprint is not touched.
pub fn fit_box(b: &Box3d, index: &PointIndex, cfg: &GroundFitConfig) -> (Box3d, FitOutcome) {
    let reach = b.bev_radius() + cfg.margin_m;
    let (bottom0, top0) = (b.bottom(), b.top());
    let mut ground_z = Vec::new();
    let mut inside = Vec::new();
    for p in index.within([b.x, b.y], reach) {
        let [u, v, _] = b.to_local([p[0] as f64, p[1] as f64, b.z]).map(f64::abs);
        if u > 0.5 * b.dx || v > 0.5 * b.dy {
            ground_z.push(p[2]);
        } else if u <= 0.5 * b.dx - cfg.top_inset_m && v <= 0.5 * b.dy - cfg.top_inset_m {
            inside.push(p[2] as f64);
        }
    }
    if ground_z.len() < cfg.min_ground_points {
        return (*b, FitOutcome::Kept);
    }
    let k = ((ground_z.len() - 1) as f64 * cfg.ground_quantile).round() as usize;
    let (_, g, _) = ground_z.select_nth_unstable_by(k, f32::total_cmp);
    let ground = *g as f64;
    if (ground - bottom0).abs() >= cfg.max_shift_m {
        return (*b, FitOutcome::Kept);
    }
    let (lo, hi) = (ground + cfg.top_min_frac * b.dz, top0 + cfg.top_reach_m);
    let (roof_points, roof_top) =
        inside.iter().filter(|z| **z > lo && **z < hi).fold((0usize, f64::MIN), |(n, m), z| (n + 1, m.max(*z)));
    let (top, outcome) = if roof_points >= cfg.min_top_points {
        (roof_top.max(top0 - cfg.top_max_lower_m), FitOutcome::GroundAndTop)
    } else {
        (top0, FitOutcome::GroundOnly)
    };
    if top - ground <= cfg.min_height_frac * b.dz {
        return (*b, FitOutcome::Kept);
    }
    (Box3d { z: 0.5 * (top + ground), dz: top - ground, ..*b }, outcome)
}

/// The index cell size used by the detectors (metres).
pub const INDEX_CELL_M: f64 = 1.0;

#[cfg(test)]
mod tests {
    use super::*;

    /// A car-sized roof of points at `top_z` inside a 4 × 2 footprint at (10, 5), heading 0.5 rad,
    /// on a flat ground at `ground_z` sampled every 0.2 m around it.
    fn scene(ground_z: f32, top_z: f32) -> (Vec<[f32; 4]>, Box3d) {
        let truth = Box3d::new(10.0, 5.0, 0.5 * (ground_z + top_z) as f64, 4.0, 2.0, (top_z - ground_z) as f64, 0.5);
        let mut pts = Vec::new();
        let (s, c) = truth.heading.sin_cos();
        for i in -40..=40 {
            for j in -40..=40 {
                let (x, y) = (10.0 + 0.2 * i as f64, 5.0 + 0.2 * j as f64);
                let (u, v) = ((c * (x - 10.0) + s * (y - 5.0)).abs(), (-s * (x - 10.0) + c * (y - 5.0)).abs());
                if u <= 2.0 && v <= 1.0 {
                    if u <= 1.6 && v <= 0.8 {
                        pts.push([x as f32, y as f32, top_z, 0.5]);
                    }
                } else {
                    pts.push([x as f32, y as f32, ground_z, 0.1]);
                }
            }
        }
        (pts, truth)
    }

    #[test]
    fn index_radius_query_equals_brute_force() {
        let pts: Vec<[f32; 4]> = (0..2000)
            .map(|k| [((k * 37) % 101) as f32 * 0.7 - 30.0, ((k * 53) % 89) as f32 * 0.6 - 20.0, 0.0, 0.0])
            .collect();
        let idx = PointIndex::new(&pts, 1.0);
        for (xy, r) in [([0.0, 0.0], 5.0), ([-30.0, -20.0], 3.0), ([40.0, 40.0], 2.0), ([100.0, 0.0], 200.0)] {
            let mut got: Vec<[f32; 3]> = idx.within(xy, r).copied().collect();
            let mut want: Vec<[f32; 3]> = pts
                .iter()
                .filter(|p| ((p[0] as f64 - xy[0]).powi(2) + (p[1] as f64 - xy[1]).powi(2)) <= r * r)
                .map(|p| [p[0], p[1], p[2]])
                .collect();
            got.sort_by(|a, b| a.partial_cmp(b).unwrap());
            want.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(got, want, "query {xy:?} r {r}");
        }
        assert_eq!(PointIndex::new(&[], 1.0).within([0.0, 0.0], 10.0).count(), 0);
    }

    #[test]
    fn a_floating_short_box_is_set_on_the_ground_and_up_to_the_roof() {
        let (pts, truth) = scene(-0.3, 1.2);
        let idx = PointIndex::new(&pts, INDEX_CELL_M);
        // Bottom 0.35 m above the ground, top 0.15 m below the roof.
        let predicted = Box3d { z: truth.z + 0.1, dz: truth.dz - 0.5, ..truth };
        let (b, outcome) = fit_box(&predicted, &idx, &GroundFitConfig::default());
        assert_eq!(outcome, FitOutcome::GroundAndTop);
        assert!((b.bottom() - -0.3).abs() < 1e-6, "bottom {}", b.bottom());
        assert!((b.top() - 1.2).abs() < 1e-6, "top {}", b.top());
        assert_eq!((b.x, b.y, b.dx, b.dy, b.heading), (truth.x, truth.y, truth.dx, truth.dy, truth.heading));
    }

    #[test]
    fn a_top_above_the_highest_point_comes_down_at_most_top_max_lower_m() {
        let (pts, truth) = scene(-0.3, 1.2);
        let idx = PointIndex::new(&pts, INDEX_CELL_M);
        // The predicted top 0.3 m above the roof: the roof may be unseen, so it comes down 0.1 m only.
        let tall = Box3d { z: truth.z + 0.15, dz: truth.dz + 0.3, ..truth };
        let cfg = GroundFitConfig::default();
        let (b, _) = fit_box(&tall, &idx, &cfg);
        assert!((b.top() - (tall.top() - cfg.top_max_lower_m)).abs() < 1e-6, "top {}", b.top());
        assert!((b.bottom() - -0.3).abs() < 1e-6, "bottom {}", b.bottom());
        // Without the limit it comes down to the roof.
        let (b, _) = fit_box(&tall, &idx, &GroundFitConfig { top_max_lower_m: f64::INFINITY, ..cfg });
        assert!((b.top() - 1.2).abs() < 1e-6, "top {}", b.top());
    }

    #[test]
    fn without_ground_or_with_a_distant_one_the_box_is_kept() {
        let (pts, truth) = scene(-0.3, 1.2);
        let cfg = GroundFitConfig::default();
        let idx = PointIndex::new(&pts, INDEX_CELL_M);
        // The predicted bottom 1.5 m above the ground: beyond max_shift_m.
        let high = Box3d { z: truth.z + 1.5, ..truth };
        assert_eq!(fit_box(&high, &idx, &cfg), (high, FitOutcome::Kept));
        // Only the roof: no ground points around.
        let roof: Vec<[f32; 4]> = pts.iter().copied().filter(|p| p[2] > 0.0).collect();
        let idx = PointIndex::new(&roof, INDEX_CELL_M);
        assert_eq!(fit_box(&truth, &idx, &cfg), (truth, FitOutcome::Kept));
        // Ground but no roof: the bottom moves, the predicted top stays.
        let ground: Vec<[f32; 4]> = pts.iter().copied().filter(|p| p[2] < 0.0).collect();
        let idx = PointIndex::new(&ground, INDEX_CELL_M);
        let low = Box3d { z: truth.z + 0.2, ..truth };
        let (b, outcome) = fit_box(&low, &idx, &cfg);
        assert_eq!(outcome, FitOutcome::GroundOnly);
        assert!((b.bottom() - -0.3).abs() < 1e-6 && (b.z + 0.5 * b.dz - (low.z + 0.5 * low.dz)).abs() < 1e-9);
    }

    #[test]
    fn bad_configs_are_errors() {
        assert!(GroundFitConfig::default().validate().is_ok());
        for bad in [
            GroundFitConfig { margin_m: 0.0, ..Default::default() },
            GroundFitConfig { max_shift_m: f64::NAN, ..Default::default() },
            GroundFitConfig { ground_quantile: 1.5, ..Default::default() },
            GroundFitConfig { min_ground_points: 0, ..Default::default() },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
