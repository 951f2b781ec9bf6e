//! Planar box fit to the frame's points, after NMS (and after the vertical fit): each long box
//! (a car, not a pedestrian) with enough points on its body gets the heading that best explains
//! them as an L- or I-shaped outline, and its centre moves so the faces the sensor sees lie on
//! the points.
//!
//! Why: after [`crate::post_process::ground_fit`], the "what if exact" rows of `pi3det eval --breakdown` put
//! the remaining Car 3D@0.7 loss on the BEV centre and the heading (measured:
//! results/2026-12-02-vertical-box-fit.md). A dense car's visible faces are measured to a few
//! centimetres; the network's regression from a 0.64 m map is not.
//!
//! Heading: the closeness criterion of L-shape fitting (Zhang et al., "Efficient L-Shape Fitting
//! for Vehicle Detection Using Laser Scanners", IV 2017), searched only near the predicted heading
//! (so a box never turns by 90° or flips). Centre: along each box axis, the points' extent must
//! fit inside the predicted length; the face turned to the sensor is where the points end, so the
//! centre is half a length behind it. An axis whose ends the sensor does not face keeps the
//! predicted centre, moved only as far as needed to hold the points. A box shorter (or narrower)
//! than its points' span grows to it by at most `max_grow_m` (the network's cars are short);
//! sizes are never shrunk. A fit that would move the centre further than `max_shift_m` is
//! dropped (an occluder, a merged neighbour).
//!
//! The defaults were chosen on one checkpoint's vehicle val split (the demo's Pi3DET-Net PA
//! model, seed 0). Measured: results/2026-12-02-planar-box-fit.md.
//!
//! Runs in the detector's frame; the sensor's planar position there comes from the frame's
//! `detector_from_lidar`. Configured as `[post.bev_fit]`; absent, boxes keep their BEV.

use pi3det_geometry::boxes::wrap_angle;
use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};

use crate::error::{NnError, Result};
use crate::post_process::ground_fit::PointIndex;

/// `[post.bev_fit]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BevFitConfig {
    /// Only boxes at least this long are fitted (pedestrians and cyclists have no flat faces).
    pub min_length_m: f64,
    /// Points within the footprint grown by this much belong to the box.
    pub margin_m: f64,
    /// Points less than this above the box's bottom are ground, not body.
    pub clearance_m: f64,
    pub min_points: usize,
    /// The heading is searched within ± this of the predicted one, in `heading_step_rad` steps.
    pub max_turn_rad: f64,
    pub heading_step_rad: f64,
    /// Closeness floor of the L-shape criterion: points nearer a face than this all count alike.
    pub closeness_floor_m: f64,
    /// A fit moving the centre further than this is dropped.
    pub max_shift_m: f64,
    /// Along an axis where the points span more than the predicted size (the network's car is
    /// short), the size grows to their span by at most this much (0: sizes are kept).
    pub max_grow_m: f64,
    /// The same limit across the box: real cars' mirrors stick out of the labelled width.
    pub max_grow_width_m: f64,
    /// Fit passes: each gathers the body points with the previous pass's box (a box placed
    /// `margin_m` off misses part of its body in the first pass).
    pub passes: usize,
}

impl Default for BevFitConfig {
    fn default() -> Self {
        Self {
            min_length_m: 2.5,
            margin_m: 0.3,
            clearance_m: 0.2,
            min_points: 10,
            max_turn_rad: 0.15,
            heading_step_rad: 0.005,
            closeness_floor_m: 0.02,
            max_shift_m: 0.8,
            max_grow_m: 0.6,
            max_grow_width_m: 0.0,
            passes: 2,
        }
    }
}

impl BevFitConfig {
    pub fn validate(&self) -> Result<()> {
        let nonneg = [
            self.min_length_m,
            self.margin_m,
            self.clearance_m,
            self.max_turn_rad,
            self.max_shift_m,
            self.max_grow_m,
            self.max_grow_width_m,
        ];
        if nonneg.iter().any(|v| !(v.is_finite() && *v >= 0.0))
            || !(self.heading_step_rad.is_finite() && self.heading_step_rad > 0.0)
            || !(self.closeness_floor_m.is_finite() && self.closeness_floor_m > 0.0)
        {
            return Err(NnError::config(
                "post.bev_fit",
                "post.bev_fit: heading_step_rad and closeness_floor_m must be positive; min_length_m, margin_m, \
                 clearance_m, max_turn_rad, max_shift_m, max_grow_m and max_grow_width_m finite and ≥ 0",
            ));
        }
        if self.min_points < 3 || self.passes == 0 {
            return Err(NnError::config(
                "post.bev_fit",
                "post.bev_fit: min_points must be at least 3 and passes at least 1",
            ));
        }
        Ok(())
    }
}

/// What the fit did to one box.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BevFitOutcome {
    Fitted,
    /// Unchanged: too short, too few body points, or the fit moved too far.
    Kept,
}

/// `p` on the axes at heading `(sin, cos)`.
#[inline]
fn project(p: [f64; 2], (s, c): (f64, f64)) -> [f64; 2] {
    [c * p[0] + s * p[1], -s * p[0] + c * p[1]]
}

/// The per-axis minimum and maximum of the points projected on the axes at `(sin, cos)`.
fn extent(points: &[[f64; 2]], sc: (f64, f64)) -> ([f64; 2], [f64; 2]) {
    points.iter().fold(([f64::MAX; 2], [f64::MIN; 2]), |(lo, hi), p| {
        let [a, b] = project(*p, sc);
        ([lo[0].min(a), lo[1].min(b)], [hi[0].max(a), hi[1].max(b)])
    })
}

/// The L-shape closeness of points `(u, v)` (box-centred) to the rectangle their extent spans
/// along the axes at `theta`: higher is closer.
fn closeness(points: &[[f64; 2]], theta: f64, floor_m: f64) -> f64 {
    let sc = theta.sin_cos();
    let (lo, hi) = extent(points, sc);
    points
        .iter()
        .map(|p| {
            let [a, b] = project(*p, sc);
            let d1 = (hi[0] - a).min(a - lo[0]);
            let d2 = (hi[1] - b).min(b - lo[1]);
            1.0 / d1.min(d2).max(floor_m)
        })
        .sum()
}

/// The centre coordinate along one box axis, relative to the predicted centre: the points span
/// `[lo, hi]`, the box is `len` long and the sensor sits at `sensor`.
fn axis_centre(lo: f64, hi: f64, len: f64, sensor: f64) -> f64 {
    if hi - lo >= len {
        return 0.5 * (lo + hi);
    }
    if sensor < lo {
        lo + 0.5 * len
    } else if sensor > hi {
        hi - 0.5 * len
    } else {
        // Neither end faces the sensor: keep the prediction, just enough moved to hold the points.
        0.0f64.clamp(hi - 0.5 * len, lo + 0.5 * len)
    }
}

/// Fits one box's heading and BEV centre (see the module docs); z is kept, sizes unless `max_grow_m`.
/// `sensor_xy` is the sensor's position in the boxes' frame.
pub fn fit_box(b: &Box3d, index: &PointIndex, sensor_xy: [f64; 2], cfg: &BevFitConfig) -> (Box3d, BevFitOutcome) {
    if b.dx.max(b.dy) < cfg.min_length_m {
        return (*b, BevFitOutcome::Kept);
    }
    let mut fitted = *b;
    for _ in 0..cfg.passes {
        match fit_pass(&fitted, [b.dx, b.dy], index, sensor_xy, cfg) {
            Some(f) => fitted = f,
            None => break,
        }
    }
    if fitted == *b || (fitted.x - b.x).hypot(fitted.y - b.y) > cfg.max_shift_m {
        return (*b, BevFitOutcome::Kept);
    }
    (fitted, BevFitOutcome::Fitted)
}

/// One pass: the body points gathered with `b`, its heading and centre fitted to them; `None`
/// when there are too few. Sizes grow to at most `predicted_size` + `max_grow_m` over all passes.
fn fit_pass(
    b: &Box3d,
    predicted_size: [f64; 2],
    index: &PointIndex,
    sensor_xy: [f64; 2],
    cfg: &BevFitConfig,
) -> Option<Box3d> {
    let (lo_z, hi_z) = (b.bottom() + cfg.clearance_m, b.top() + cfg.margin_m);
    let (hu, hv) = (0.5 * b.dx + cfg.margin_m, 0.5 * b.dy + cfg.margin_m);
    // Box-centred world axes (not rotated), so every heading is scored on the same points.
    let body: Vec<[f64; 2]> = index
        .within([b.x, b.y], b.bev_radius() + cfg.margin_m)
        .filter(|p| (p[2] as f64) > lo_z && (p[2] as f64) < hi_z)
        .filter_map(|p| {
            let [u, v, _] = b.to_local([p[0] as f64, p[1] as f64, b.z]);
            (u.abs() <= hu && v.abs() <= hv).then(|| [p[0] as f64 - b.x, p[1] as f64 - b.y])
        })
        .collect();
    if body.len() < cfg.min_points {
        return None;
    }
    let steps = (cfg.max_turn_rad / cfg.heading_step_rad).floor() as i64;
    let heading = (-steps..=steps)
        .map(|k| b.heading + k as f64 * cfg.heading_step_rad)
        // Ties go to the smaller turn.
        .map(|h| (closeness(&body, h, cfg.closeness_floor_m), -(h - b.heading).abs(), h))
        .max_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)))
        .map_or(b.heading, |t| t.2);
    let (s, c) = heading.sin_cos();
    let (lo, hi) = extent(&body, (s, c));
    let sensor = project([sensor_xy[0] - b.x, sensor_xy[1] - b.y], (s, c));
    let grown = |span: f64, len: f64, pred: f64, max: f64| if span > len && span - pred <= max { span } else { len };
    let dx = grown(hi[0] - lo[0], b.dx, predicted_size[0], cfg.max_grow_m);
    let dy = grown(hi[1] - lo[1], b.dy, predicted_size[1], cfg.max_grow_width_m);
    let cu = axis_centre(lo[0], hi[0], dx, sensor[0]);
    let cv = axis_centre(lo[1], hi[1], dy, sensor[1]);
    Some(Box3d { x: b.x + c * cu - s * cv, y: b.y + s * cu + c * cv, dx, dy, heading: wrap_angle(heading), ..*b })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::post_process::ground_fit::INDEX_CELL_M;

    /// Points on the two faces of `truth` that a sensor at the origin sees (every 5 cm, at three
    /// heights), plus a flat ground at its bottom.
    fn seen_faces(truth: &Box3d) -> Vec<[f32; 4]> {
        let mut pts = Vec::new();
        let sensor = truth.to_local([0.0, 0.0, truth.z]);
        let (hu, hv) = (0.5 * truth.dx, 0.5 * truth.dy);
        let (su, sv) = (sensor[0].signum(), sensor[1].signum());
        let (s, c) = truth.heading.sin_cos();
        let mut push = |u: f64, v: f64| {
            for w in [0.3, 0.8, 1.3] {
                let (x, y) = (truth.x + c * u - s * v, truth.y + s * u + c * v);
                pts.push([x as f32, y as f32, (truth.bottom() + w) as f32, 0.5]);
            }
        };
        for k in 0..=(truth.dy / 0.05) as i64 {
            push(su * hu, -hv + 0.05 * k as f64);
        }
        for k in 0..=(truth.dx / 0.05) as i64 {
            push(-hu + 0.05 * k as f64, sv * hv);
        }
        for i in -60..=60 {
            for j in -60..=60 {
                let (x, y) = (truth.x + 0.1 * i as f64, truth.y + 0.1 * j as f64);
                if !(Box3d { dz: 10.0, ..*truth }).contains([x, y, truth.z]) {
                    pts.push([x as f32, y as f32, truth.bottom() as f32, 0.1]);
                }
            }
        }
        pts
    }

    #[test]
    fn a_turned_shifted_car_goes_back_onto_its_seen_faces() {
        let truth = Box3d::new(12.0, 6.0, 0.8, 4.5, 1.9, 1.6, 1.2);
        let idx = PointIndex::new(&seen_faces(&truth), INDEX_CELL_M);
        let predicted = Box3d { x: truth.x + 0.35, y: truth.y - 0.25, heading: truth.heading + 0.09, ..truth };
        let (b, outcome) = fit_box(&predicted, &idx, [0.0, 0.0], &BevFitConfig::default());
        assert_eq!(outcome, BevFitOutcome::Fitted);
        assert!((b.heading - truth.heading).abs() < 0.006, "heading {} vs {}", b.heading, truth.heading);
        assert!((b.x - truth.x).hypot(b.y - truth.y) < 0.05, "centre ({}, {}) vs ({}, {})", b.x, b.y, truth.x, truth.y);
        assert_eq!((b.z, b.dz), (predicted.z, predicted.dz));
        // The span seen at the fitted heading may exceed the true size by a little.
        assert!((b.dx - truth.dx).abs() < 0.03 && (b.dy - truth.dy).abs() < 0.03, "{b:?}");
        // A box 0.4 m too short grows to the seen length, never by more than max_grow_m.
        let short = Box3d { dx: truth.dx - 0.4, ..predicted };
        let (b, _) = fit_box(&short, &idx, [0.0, 0.0], &BevFitConfig::default());
        assert!((b.dx - truth.dx).abs() < 0.06 && (b.x - truth.x).hypot(b.y - truth.y) < 0.06, "{b:?}");
        let fixed = BevFitConfig { max_grow_m: 0.0, ..BevFitConfig::default() };
        assert_eq!(fit_box(&short, &idx, [0.0, 0.0], &fixed).0.dx, short.dx);
        let little = BevFitConfig { max_grow_m: 0.3, ..BevFitConfig::default() };
        assert!(fit_box(&short, &idx, [0.0, 0.0], &little).0.dx <= short.dx + 0.3 + 1e-9);
    }

    #[test]
    fn short_sparse_or_far_moved_boxes_are_kept() {
        let cfg = BevFitConfig::default();
        let truth = Box3d::new(12.0, 6.0, 0.8, 4.5, 1.9, 1.6, 0.4);
        let idx = PointIndex::new(&seen_faces(&truth), INDEX_CELL_M);
        let pedestrian = Box3d { dx: 0.6, dy: 0.6, ..truth };
        assert_eq!(fit_box(&pedestrian, &idx, [0.0, 0.0], &cfg).1, BevFitOutcome::Kept);
        // Only the ground around: no body points.
        let empty = PointIndex::new(&[], INDEX_CELL_M);
        assert_eq!(fit_box(&truth, &empty, [0.0, 0.0], &cfg), (truth, BevFitOutcome::Kept));
        // A fit that would move the centre by ~0.7 m is refused under a 0.3 m limit.
        let off = Box3d { x: truth.x + 0.5, y: truth.y + 0.5, ..truth };
        let strict = BevFitConfig { max_shift_m: 0.3, ..cfg.clone() };
        assert_eq!(fit_box(&off, &idx, [0.0, 0.0], &strict), (off, BevFitOutcome::Kept));
    }

    #[test]
    fn an_axis_seen_from_the_side_keeps_its_predicted_centre() {
        // Sensor beside the car (its u within the car's length): only the near long face is seen.
        let truth = Box3d::new(0.5, 8.0, 0.8, 4.5, 1.9, 1.6, 0.0);
        let mut pts = Vec::new();
        for k in 0..=60 {
            for w in [0.3, 0.8, 1.3] {
                pts.push([(truth.x - 1.5 + 0.05 * k as f64) as f32, (truth.y - 0.95) as f32, w, 0.5]);
            }
        }
        let idx = PointIndex::new(&pts, INDEX_CELL_M);
        let predicted = Box3d { x: truth.x + 0.2, y: truth.y + 0.2, ..truth };
        let (b, _) = fit_box(&predicted, &idx, [0.0, 0.0], &BevFitConfig::default());
        // v: the near face (y = 7.05) sets the centre half a width behind it; u: the 3 m of seen
        // face fit inside the 4.5 m box with the predicted centre, which is kept.
        assert!((b.y - truth.y).abs() < 1e-6 && (b.x - predicted.x).abs() < 1e-6, "({}, {})", b.x, b.y);
    }

    #[test]
    fn bad_configs_are_errors() {
        assert!(BevFitConfig::default().validate().is_ok());
        for bad in [
            BevFitConfig { heading_step_rad: 0.0, ..Default::default() },
            BevFitConfig { margin_m: -1.0, ..Default::default() },
            BevFitConfig { closeness_floor_m: f64::NAN, ..Default::default() },
            BevFitConfig { min_points: 1, ..Default::default() },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
