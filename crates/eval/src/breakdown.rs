//! Error breakdown of a detector beyond the AP table: where it fails (by distance, by points per
//! box), whether its misses are boxes found but misplaced, and how far its boxes are off.
//!
//! Everything is computed per evaluated class at the class's main thresholds, the report's
//! strict set (Car BEV / 3D 0.7, Pedestrian and Cyclist 0.5), on the ground-truth states of the
//! moderate difficulty (on datasets without KITTI fields every difficulty is the same), with
//! the same filters, name mapping and matching as [`crate::evaluate()`]; the `all` row is the
//! report's moderate BEV / 3D AP_R40 exactly.
//!
//! * **Bins.** A bin keeps the protocol and changes only who counts. Ground truths of the class
//!   outside the bin become ignore regions (the protocol's "ignored" state: a detection matching
//!   one is neither TP nor FP), so bin borders create no false positives.
//!   - *Distance* (BEV distance of the LiDAR box centre from the sensor origin, `[min, max)` m):
//!     detections are binned by their own centre distance as well; those outside the bin are
//!     ignored detections (never FP; an in-bin GT whose only match lies just across the border
//!     is then neither TP nor FN), so the border creates no artificial misses either.
//!   - *Points* (the dataset's stored count of LiDAR points in the GT box, bounds included):
//!     detections have no point count, so all of them take part in every bin, and a detection
//!     matching no ground truth at all is a false positive in every bin. AP in a sparse bin is
//!     therefore a conservative (lower-bound) figure; recall is the primary number there. Ground
//!     truths without a stored count are in no points bin (counted in `gt_without_points`).
//! * **Recall** at the operating point of all detections: the share of the bin's ground truths
//!   that the protocol's matching (each GT in turn takes the free detection of largest overlap
//!   strictly above the threshold) gives any detection, all scores active; a detection the bin
//!   ignores (centre across a distance border) still counts as finding its ground truth.
//! * **Found but misplaced**: among the ground truths missed at the main threshold (by the same
//!   matching), those with a detection of the class that the matching left free at overlap
//!   ≥ [`LOOSE_IOU`] (BEV for BEV misses, 3D for 3D misses). Detections taken by another ground
//!   truth do not count: they were not misplaced copies of this one.
//! * **Localisation errors**: ground truths and detections of the class are paired one to one,
//!   greedily by BEV IoU (largest first; ties by GT then detection index), pairs with BEV IoU
//!   ≥ [`LOOSE_IOU`]; scores play no part, so these are the errors of the best-placed box per
//!   object (use a score threshold to restrict them to confident ones). Errors are detection
//!   minus ground truth in the LiDAR frame; heading is compared modulo π (AP ignores direction),
//!   wrapped to [−π/2, π/2).
//!
//! * **What if exact**: the same localisation pairs, with the named components of each paired
//!   detection replaced by its ground truth's (`z`, `height`, both, the BEV centre, length and
//!   width, heading), re-evaluated with the protocol: the AP each error costs. Unpaired
//!   detections and ground truths stay as they are, so AP with every component exact is the
//!   class's AP at the loose IoU, not 100. A row can lower AP: a detection that describes its
//!   box with length and width swapped and the heading turned by π/2 (the same box) is broken by
//!   making only its heading, or only its size, exact — small square-ish boxes (pedestrians).
//!
//! Empty bins and undefined shares are `None` (`null` in JSON), never NaN.

use std::collections::BTreeSet;
use std::f64::consts::PI;
use std::fmt::Write as _;

use pi3det_data::{Dataset, FrameInfo};
use pi3det_geometry::Box3d;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::anno::KittiFrame;
use crate::ap::{ap_r40, curves, get_thresholds, PrCounts, N_SAMPLE_PTS};
use crate::classes::NameMap;
use crate::convert::{self, LidarGt};
use crate::detections::Detections;
use crate::difficulty::DIFFICULTIES;
use crate::error::EvalError;
use crate::matching::{Pass, Scratch};
use crate::options::EvalOptions;
use crate::prepare::{PreparedFrame, States};
use crate::protocol::{check_finite, ClassSpec};
use crate::run::{check_inputs, filter};

/// The difficulty whose ground-truth states the breakdown uses: moderate, the paper's column.
const DIFFICULTY: usize = 1;

/// Overlap (BEV or 3D IoU) from which a free detection makes a miss "found but misplaced", and
/// from which a GT–detection pair enters the localisation errors.
pub const LOOSE_IOU: f64 = 0.1;

/// Distance bins `[min_m, max_m)`; `None`: no upper bound.
pub const DISTANCE_BINS_M: [(f64, Option<f64>); 3] = [(0.0, Some(20.0)), (20.0, Some(40.0)), (40.0, None)];

/// Points-per-box bins `[min, max]`, bounds included; `None`: no upper bound.
pub const POINTS_BINS: [(u32, Option<u32>); 3] = [(0, Some(20)), (21, Some(100)), (101, None)];

/// The error breakdown of one evaluation (serialised as the `breakdown` field of `--json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Breakdown {
    /// KITTI difficulty of the ground-truth states used ("moderate").
    pub difficulty: String,
    /// [`LOOSE_IOU`].
    pub loose_iou: f64,
    pub classes: Vec<ClassBreakdown>,
}

/// The breakdown of one class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassBreakdown {
    pub class: String,
    /// Main BEV IoU threshold (the report's strict set).
    pub min_iou_bev: f64,
    /// Main 3D IoU threshold (the report's strict set).
    pub min_iou_3d: f64,
    /// The whole split: AP equals the report's moderate R40 at the main thresholds.
    pub all: BinResult,
    pub by_distance: Vec<DistanceBin>,
    pub by_points: Vec<PointsBin>,
    /// Counted ground truths without a stored point count: in no points bin.
    pub gt_without_points: usize,
    pub misplaced: Misplaced,
    pub localisation: Localisation,
    /// AP with components of the paired detections made exact, in [`WHAT_IF`]'s order (absent
    /// from breakdowns written before it existed).
    #[serde(default)]
    pub what_if: Vec<WhatIf>,
}

/// Components of a box a "what if" row takes from the ground truth: name and indices into
/// `[x, y, z, dx, dy, dz, heading]`.
pub const WHAT_IF: [(&str, &[usize]); 6] = [
    ("z", &[2]),
    ("height", &[5]),
    ("z+height", &[2, 5]),
    ("xy", &[0, 1]),
    ("length+width", &[3, 4]),
    ("heading", &[6]),
];

/// The class's AP at its main thresholds with some components of every paired detection exact.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WhatIf {
    /// What was made exact (a [`WHAT_IF`] name).
    pub exact: String,
    pub ap_bev_r40_pct: Option<f64>,
    pub ap_3d_r40_pct: Option<f64>,
}

/// AP and recall of one bin. `None` where the bin has no ground truth (or, for AP, where the
/// reference's precision would be 0/0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BinResult {
    /// Ground truths that count in this bin.
    pub num_gt: usize,
    /// Of them, matched by some detection at the main BEV threshold (all scores).
    pub found_bev: usize,
    /// Of them, matched by some detection at the main 3D threshold (all scores).
    pub found_3d: usize,
    /// `found_bev / num_gt` (a fraction, 0–1).
    pub recall_bev: Option<f64>,
    /// `found_3d / num_gt` (a fraction, 0–1).
    pub recall_3d: Option<f64>,
    /// BEV AP_R40 in percent.
    pub ap_bev_r40_pct: Option<f64>,
    /// 3D AP_R40 in percent.
    pub ap_3d_r40_pct: Option<f64>,
}

/// A distance bin: BEV distance of the box centre from the sensor origin in `[min_m, max_m)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DistanceBin {
    pub min_m: f64,
    /// `None`: no upper bound.
    pub max_m: Option<f64>,
    /// Detections of the class whose centre lies in the bin.
    pub num_det: usize,
    #[serde(flatten)]
    pub result: BinResult,
}

/// A points bin: stored points in the ground-truth box in `[min_points, max_points]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PointsBin {
    pub min_points: u32,
    /// `None`: no upper bound.
    pub max_points: Option<u32>,
    #[serde(flatten)]
    pub result: BinResult,
}

/// Misses at the main thresholds that have a free detection of the class at overlap ≥
/// [`LOOSE_IOU`] ("found but misplaced").
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Misplaced {
    /// Counted ground truths missed at the main BEV threshold.
    pub missed_bev: usize,
    /// Of them, with a free detection at BEV IoU ≥ [`LOOSE_IOU`].
    pub misplaced_bev: usize,
    /// `misplaced_bev / missed_bev` (0–1); `None` without misses.
    pub share_bev: Option<f64>,
    /// Counted ground truths missed at the main 3D threshold.
    pub missed_3d: usize,
    /// Of them, with a free detection at 3D IoU ≥ [`LOOSE_IOU`].
    pub misplaced_3d: usize,
    /// `misplaced_3d / missed_3d` (0–1); `None` without misses.
    pub share_3d: Option<f64>,
}

/// Localisation errors of the GT–detection pairs (see the module docs for the pairing).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Localisation {
    pub num_pairs: usize,
    /// `None` without pairs.
    pub errors: Option<BoxErrors>,
}

/// Per box parameter, detection minus ground truth (LiDAR frame, `z` the box centre).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BoxErrors {
    pub x_m: AxisError,
    pub y_m: AxisError,
    pub z_m: AxisError,
    pub dx_m: AxisError,
    pub dy_m: AxisError,
    pub dz_m: AxisError,
    /// Compared modulo π, wrapped to [−π/2, π/2).
    pub heading_rad: AxisError,
}

/// Statistics of one error, in the unit its field name gives.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AxisError {
    /// Median of the absolute error.
    pub median_abs: f64,
    /// Mean of the absolute error.
    pub mean_abs: f64,
    /// Mean of the signed error (the bias; positive: detections too large / too far along +axis).
    pub mean_signed: f64,
}

/// Reads every frame's annotations of a dataset (in parallel) and computes the breakdown.
pub fn breakdown_dataset(ds: &dyn Dataset, dets: &Detections, opts: &EvalOptions) -> Result<Breakdown, EvalError> {
    let infos: Vec<FrameInfo> = ds.infos()?;
    breakdown(&infos, dets, opts)
}

/// The error breakdown of detections against ground-truth frames (matched by frame id), with
/// the same options, checks and classes as [`crate::evaluate()`].
pub fn breakdown(gt: &[FrameInfo], dets: &Detections, opts: &EvalOptions) -> Result<Breakdown, EvalError> {
    check_inputs(gt, dets, opts)?;
    let names = NameMap::new(&opts.name_map);
    let filter = filter(opts, &names);
    let converted: Vec<_> = gt
        .par_iter()
        .map(|info| {
            let d = dets.frames.get(&info.id).map(Vec::as_slice).unwrap_or(&[]);
            (convert::ground_truth_lidar(info, &filter), convert::detections_lidar(info, d, &filter))
        })
        .collect();
    let (mut gts, mut dts, mut gt_lidar, mut dt_lidar) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for ((g, gl), (d, dl)) in converted {
        gts.push(g);
        gt_lidar.push(gl);
        dts.push(d);
        dt_lidar.push(dl);
    }
    let present: BTreeSet<&str> = gts.iter().flat_map(|g| g.objects.iter().map(|o| o.name.as_str())).collect();
    let classes = opts.class_specs(present)?;
    check_finite(&gts, &dts)?;
    let classes_lc: Vec<String> = classes.iter().map(|c| c.name.to_lowercase()).collect();
    let prepared: Vec<PreparedFrame> =
        gts.par_iter().zip(dts.par_iter()).map(|(g, d)| PreparedFrame::new(g, d, &classes_lc)).collect();
    let split = Split { prepared: &prepared, dts: &dts, gt_lidar: &gt_lidar, dt_lidar: &dt_lidar };
    let classes = classes
        .iter()
        .enumerate()
        .map(|(c, spec)| {
            let mut b = split.class(c, spec);
            b.what_if = split.what_if(gt, &gts, c, spec, &classes_lc);
            b
        })
        .collect();
    Ok(Breakdown { difficulty: DIFFICULTIES[DIFFICULTY].to_string(), loose_iou: LOOSE_IOU, classes })
}

/// The converted split, frame by frame.
struct Split<'a> {
    prepared: &'a [PreparedFrame],
    dts: &'a [KittiFrame],
    gt_lidar: &'a [Vec<LidarGt>],
    dt_lidar: &'a [Vec<Box3d>],
}

fn bev_distance_m(b: &Box3d) -> f64 {
    b.x.hypot(b.y)
}

fn ratio(n: usize, d: usize) -> Option<f64> {
    (d > 0).then(|| n as f64 / d as f64)
}

/// `base` with counted ground truths outside the bin made ignored, and counted detections
/// outside it too (`dt_in` always true: detections stay as they are).
fn restrict(base: &States, gt_in: impl Fn(usize) -> bool, dt_in: impl Fn(usize) -> bool) -> States {
    let gt: Vec<i8> = base.gt.iter().enumerate().map(|(i, &s)| if s == 0 && !gt_in(i) { 1 } else { s }).collect();
    let dt = base.dt.iter().enumerate().map(|(j, &s)| if s == 0 && !dt_in(j) { 1 } else { s }).collect();
    States { num_valid_gt: gt.iter().filter(|&&s| s == 0).count(), gt, dt }
}

impl Split<'_> {
    fn pass<'a>(&'a self, f: usize, states: &'a States, metric: usize, min_overlap: f64) -> Pass<'a> {
        Pass { frame: &self.prepared[f], states, metric, min_overlap }
    }

    /// The protocol's AP_R40 (threshold pass, PR pass, curves) with these states per frame.
    fn ap_r40(&self, states: &[States], metric: usize, min_overlap: f64) -> f64 {
        let mut scores: Vec<f64> = (0..states.len())
            .into_par_iter()
            .fold(
                || (Vec::new(), Scratch::default()),
                |(mut out, mut scratch), f| {
                    self.pass(f, &states[f], metric, min_overlap).tp_scores(&mut scratch, &mut out);
                    (out, scratch)
                },
            )
            .map(|(out, _)| out)
            .reduce(Vec::new, |mut a, b| {
                a.extend(b);
                a
            });
        let num_gt = states.iter().map(|s| s.num_valid_gt).sum();
        let thresholds = get_thresholds(&mut scores, num_gt);
        let empty = || [PrCounts::default(); N_SAMPLE_PTS];
        let pr = (0..states.len())
            .into_par_iter()
            .fold(
                || (empty(), Scratch::default()),
                |(mut acc, mut scratch), f| {
                    self.pass(f, &states[f], metric, min_overlap).accumulate(&thresholds, &mut scratch, &mut acc);
                    (acc, scratch)
                },
            )
            .map(|(acc, _)| acc)
            .reduce(empty, |mut a, b| {
                for (p, q) in a.iter_mut().zip(b) {
                    p.tp += q.tp;
                    p.fp += q.fp;
                    p.fn_ += q.fn_;
                    p.similarity += q.similarity;
                }
                a
            });
        ap_r40(&curves(&pr[..thresholds.len()]).precision)
    }

    /// Counted ground truths the matching gives a detection, all scores active.
    fn found(&self, states: &[States], metric: usize, min_overlap: f64) -> usize {
        (0..states.len())
            .into_par_iter()
            .map(|f| {
                let a = self.pass(f, &states[f], metric, min_overlap).assignment(f64::NEG_INFINITY);
                a.iter().zip(&states[f].gt).filter(|(m, &g)| g == 0 && m.is_some()).count()
            })
            .sum()
    }

    fn bin(&self, states: &[States], min_iou: [f64; 2]) -> BinResult {
        let num_gt: usize = states.iter().map(|s| s.num_valid_gt).sum();
        let [found_bev, found_3d] = [0, 1].map(|k| self.found(states, k + 1, min_iou[k]));
        // NaN (0/0 precision) is the reference's "undefined": None, like an empty bin.
        let ap = |k: usize| (num_gt > 0).then(|| self.ap_r40(states, k + 1, min_iou[k])).filter(|v| v.is_finite());
        BinResult {
            num_gt,
            found_bev,
            found_3d,
            recall_bev: ratio(found_bev, num_gt),
            recall_3d: ratio(found_3d, num_gt),
            ap_bev_r40_pct: ap(0),
            ap_3d_r40_pct: ap(1),
        }
    }

    fn class(&self, c: usize, spec: &ClassSpec) -> ClassBreakdown {
        let min_iou = [spec.overlaps.strict[1], spec.overlaps.strict[2]];
        let base: Vec<States> = self.prepared.iter().map(|p| p.states[c][DIFFICULTY].clone()).collect();
        let is_class = self.is_class(spec);
        // DontCare regions come after the objects and have no LiDAR box: in no bin.
        let gt_lidar = |f: usize, i: usize| self.gt_lidar[f].get(i);

        let by_distance = DISTANCE_BINS_M
            .iter()
            .map(|&(min_m, max_m)| {
                let inside = |b: &Box3d| {
                    let d = bev_distance_m(b);
                    d >= min_m && max_m.is_none_or(|m| d < m)
                };
                let states: Vec<States> = (0..base.len())
                    .map(|f| {
                        restrict(
                            &base[f],
                            |i| gt_lidar(f, i).is_some_and(|g| inside(&g.box3d)),
                            |j| inside(&self.dt_lidar[f][j]),
                        )
                    })
                    .collect();
                let num_det = (0..base.len())
                    .map(|f| self.dt_lidar[f].iter().zip(&is_class[f]).filter(|(b, &k)| k && inside(b)).count())
                    .sum();
                DistanceBin { min_m, max_m, num_det, result: self.bin(&states, min_iou) }
            })
            .collect();

        let by_points = POINTS_BINS
            .iter()
            .map(|&(min_points, max_points)| {
                let inside = |n: u32| n >= min_points && max_points.is_none_or(|m| n <= m);
                let states: Vec<States> = (0..base.len())
                    .map(|f| {
                        restrict(&base[f], |i| gt_lidar(f, i).and_then(|g| g.num_points).is_some_and(inside), |_| true)
                    })
                    .collect();
                PointsBin { min_points, max_points, result: self.bin(&states, min_iou) }
            })
            .collect();
        let gt_without_points = (0..base.len())
            .map(|f| {
                (0..base[f].gt.len())
                    .filter(|&i| base[f].gt[i] == 0 && gt_lidar(f, i).is_none_or(|g| g.num_points.is_none()))
                    .count()
            })
            .sum();

        ClassBreakdown {
            class: spec.name.clone(),
            min_iou_bev: min_iou[0],
            min_iou_3d: min_iou[1],
            all: self.bin(&base, min_iou),
            by_distance,
            by_points,
            gt_without_points,
            misplaced: self.misplaced(&base, &is_class, min_iou),
            localisation: self.localisation(&base, &is_class),
            what_if: Vec::new(),
        }
    }

    /// Whether each detection of each frame is of class `spec`.
    fn is_class(&self, spec: &ClassSpec) -> Vec<Vec<bool>> {
        let class_lc = spec.name.to_lowercase();
        self.dts.iter().map(|d| d.objects.iter().map(|o| o.name.to_lowercase() == class_lc).collect()).collect()
    }

    /// The [`WHAT_IF`] rows of class `c` (see the module docs).
    fn what_if(
        &self,
        infos: &[FrameInfo],
        gts: &[KittiFrame],
        c: usize,
        spec: &ClassSpec,
        classes_lc: &[String],
    ) -> Vec<WhatIf> {
        let min_iou = [spec.overlaps.strict[1], spec.overlaps.strict[2]];
        let base: Vec<States> = self.prepared.iter().map(|p| p.states[c][DIFFICULTY].clone()).collect();
        let is_class = self.is_class(spec);
        let pairs: Vec<Vec<(usize, usize)>> =
            (0..base.len()).into_par_iter().map(|f| self.pairs(f, &base[f], &is_class[f])).collect();
        WHAT_IF
            .iter()
            .map(|&(name, components)| {
                let prepared: Vec<PreparedFrame> = (0..base.len())
                    .into_par_iter()
                    .map(|f| {
                        let mut dt = self.dts[f].clone();
                        for &(i, j) in &pairs[f] {
                            let mut b = self.dt_lidar[f][j].to_array();
                            let g = self.gt_lidar[f][i].box3d.to_array();
                            for &k in components {
                                b[k] = g[k];
                            }
                            convert::set_detection_box(&infos[f], &mut dt.objects[j], &Box3d::from_array(b));
                        }
                        // Only this class: its states do not depend on the others.
                        PreparedFrame::new(&gts[f], &dt, std::slice::from_ref(&classes_lc[c]))
                    })
                    .collect();
                let split = Split { prepared: &prepared, ..*self };
                let states: Vec<States> = prepared.iter().map(|p| p.states[0][DIFFICULTY].clone()).collect();
                let r = split.bin(&states, min_iou);
                WhatIf { exact: name.to_string(), ap_bev_r40_pct: r.ap_bev_r40_pct, ap_3d_r40_pct: r.ap_3d_r40_pct }
            })
            .collect()
    }

    /// Counted ground truths and detections of the class of frame `f`, paired one to one
    /// greedily by BEV IoU ≥ [`LOOSE_IOU`] (largest first; ties by GT then detection index).
    fn pairs(&self, f: usize, st: &States, is_class: &[bool]) -> Vec<(usize, usize)> {
        let rows = &self.prepared[f].overlaps[1];
        let mut cand: Vec<(f64, usize, usize)> = Vec::new();
        for i in (0..st.gt.len()).filter(|&i| st.gt[i] == 0 && i < self.gt_lidar[f].len()) {
            for &(j, ov) in rows.row(i) {
                if ov >= LOOSE_IOU && is_class[j as usize] {
                    cand.push((ov, i, j as usize));
                }
            }
        }
        cand.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let (mut gt_used, mut dt_used) = (vec![false; st.gt.len()], vec![false; st.dt.len()]);
        let mut out = Vec::new();
        for (_, i, j) in cand {
            if !gt_used[i] && !dt_used[j] {
                gt_used[i] = true;
                dt_used[j] = true;
                out.push((i, j));
            }
        }
        out
    }

    fn misplaced(&self, base: &[States], is_class: &[Vec<bool>], min_iou: [f64; 2]) -> Misplaced {
        let [(missed_bev, misplaced_bev), (missed_3d, misplaced_3d)] = [0, 1].map(|k| {
            let metric = k + 1;
            (0..base.len())
                .into_par_iter()
                .map(|f| {
                    let st = &base[f];
                    let a = self.pass(f, st, metric, min_iou[k]).assignment(f64::NEG_INFINITY);
                    let mut taken = vec![false; st.dt.len()];
                    for &j in a.iter().flatten() {
                        taken[j] = true;
                    }
                    let rows = &self.prepared[f].overlaps[metric];
                    let missed: Vec<usize> = (0..st.gt.len()).filter(|&i| st.gt[i] == 0 && a[i].is_none()).collect();
                    let misplaced = missed
                        .iter()
                        .filter(|&&i| {
                            rows.row(i).iter().any(|&(j, ov)| {
                                let j = j as usize;
                                ov >= LOOSE_IOU && is_class[f][j] && !taken[j]
                            })
                        })
                        .count();
                    (missed.len(), misplaced)
                })
                .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
        });
        Misplaced {
            missed_bev,
            misplaced_bev,
            share_bev: ratio(misplaced_bev, missed_bev),
            missed_3d,
            misplaced_3d,
            share_3d: ratio(misplaced_3d, missed_3d),
        }
    }

    fn localisation(&self, base: &[States], is_class: &[Vec<bool>]) -> Localisation {
        let errors: Vec<[f64; 7]> = (0..base.len())
            .into_par_iter()
            .flat_map_iter(|f| {
                self.pairs(f, &base[f], &is_class[f])
                    .into_iter()
                    .map(move |(i, j)| box_error(&self.dt_lidar[f][j], &self.gt_lidar[f][i].box3d))
            })
            .collect();
        let stats = |k: usize| axis_error(errors.iter().map(|e| e[k]).collect());
        let errors_of = || BoxErrors {
            x_m: stats(0),
            y_m: stats(1),
            z_m: stats(2),
            dx_m: stats(3),
            dy_m: stats(4),
            dz_m: stats(5),
            heading_rad: stats(6),
        };
        Localisation { num_pairs: errors.len(), errors: (!errors.is_empty()).then(errors_of) }
    }
}

/// Heading difference modulo π, in [−π/2, π/2): a box turned by π is the same box for IoU.
pub fn heading_error_mod_pi(det_rad: f64, gt_rad: f64) -> f64 {
    let d = (det_rad - gt_rad).rem_euclid(PI);
    if d >= 0.5 * PI {
        d - PI
    } else {
        d
    }
}

fn box_error(d: &Box3d, g: &Box3d) -> [f64; 7] {
    [d.x - g.x, d.y - g.y, d.z - g.z, d.dx - g.dx, d.dy - g.dy, d.dz - g.dz, heading_error_mod_pi(d.heading, g.heading)]
}

/// Statistics of a non-empty list of signed errors.
fn axis_error(signed: Vec<f64>) -> AxisError {
    let n = signed.len().max(1) as f64;
    let mean_signed = signed.iter().sum::<f64>() / n;
    let mut abs: Vec<f64> = signed.iter().map(|v| v.abs()).collect();
    abs.sort_unstable_by(f64::total_cmp);
    let mean_abs = abs.iter().sum::<f64>() / n;
    let median_abs = match abs.len() {
        0 => 0.0,
        len if len % 2 == 1 => abs[len / 2],
        len => 0.5 * (abs[len / 2 - 1] + abs[len / 2]),
    };
    AxisError { median_abs, mean_abs, mean_signed }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".to_string(), |v| format!("{v:.digits$}"))
}

fn pct(v: Option<f64>) -> String {
    v.map_or_else(|| "–".to_string(), |v| format!("{:.1}%", 100.0 * v))
}

fn bin_line(out: &mut String, label: &str, num_det: Option<usize>, r: &BinResult) {
    let line = format!(
        "  {label:<12} {:>6} {:>6}  {:>6} / {:<6}  {:>5} / {:<5}",
        r.num_gt,
        num_det.map_or_else(|| "·".to_string(), |n| n.to_string()),
        opt(r.ap_bev_r40_pct, 2),
        opt(r.ap_3d_r40_pct, 2),
        opt(r.recall_bev, 3),
        opt(r.recall_3d, 3),
    );
    let _ = writeln!(out, "{}", line.trim_end());
}

/// The breakdown as text: per class a table of bins (GT, detections, AP_R40 BEV / 3D, recall
/// BEV / 3D), the found-but-misplaced shares and the localisation errors.
pub fn format_breakdown(b: &Breakdown) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Error breakdown ({} difficulty; AP_R40 in %, recall with all detections; – : empty)",
        b.difficulty
    );
    for c in &b.classes {
        let _ = writeln!(out, "\n{} at IoU BEV {:.2} / 3D {:.2}", c.class, c.min_iou_bev, c.min_iou_3d);
        let _ =
            writeln!(out, "  {:<12} {:>6} {:>6}  {:>15}  {:>13}", "bin", "GT", "det", "AP BEV / 3D", "recall BEV / 3D");
        bin_line(&mut out, "all", None, &c.all);
        for d in &c.by_distance {
            let label = match d.max_m {
                Some(m) => format!("{:.0}-{m:.0} m", d.min_m),
                None => format!("{:.0}+ m", d.min_m),
            };
            bin_line(&mut out, &label, Some(d.num_det), &d.result);
        }
        for p in &c.by_points {
            let label = match (p.min_points, p.max_points) {
                (0, Some(m)) => format!("≤{m} pts"),
                (lo, Some(m)) => format!("{lo}-{m} pts"),
                (lo, None) => format!(">{} pts", lo.saturating_sub(1)),
            };
            bin_line(&mut out, &label, None, &p.result);
        }
        let _ = writeln!(
            out,
            "  points bins: AP is a lower bound (unmatched detections are FP in every bin), recall is the primary number{}",
            if c.gt_without_points > 0 {
                format!("; {} GT have no stored point count and are skipped", c.gt_without_points)
            } else {
                String::new()
            }
        );
        let m = &c.misplaced;
        let _ = writeln!(
            out,
            "  found but misplaced: BEV {} of {} missed ({}), 3D {} of {} missed ({}) have a free {} at IoU ≥ {}",
            m.misplaced_bev,
            m.missed_bev,
            pct(m.share_bev),
            m.misplaced_3d,
            m.missed_3d,
            pct(m.share_3d),
            c.class,
            b.loose_iou
        );
        let l = &c.localisation;
        let _ = writeln!(
            out,
            "  localisation, detection − GT over {} pairs (one to one, greedy by BEV IoU ≥ {}):",
            l.num_pairs, b.loose_iou
        );
        if !c.what_if.is_empty() {
            let rows: Vec<String> = c
                .what_if
                .iter()
                .map(|w| format!("{} {} / {}", w.exact, opt(w.ap_bev_r40_pct, 1), opt(w.ap_3d_r40_pct, 1)))
                .collect();
            let _ = writeln!(out, "  AP BEV / 3D with the paired GT's (what if exact): {}", rows.join(", "));
        }
        if let Some(e) = &l.errors {
            let _ = writeln!(out, "    {:<14} {:>10} {:>10} {:>10}", "", "median|e|", "mean|e|", "mean e");
            for (name, a) in [
                ("x (m)", &e.x_m),
                ("y (m)", &e.y_m),
                ("z (m)", &e.z_m),
                ("dx (m)", &e.dx_m),
                ("dy (m)", &e.dy_m),
                ("dz (m)", &e.dz_m),
                ("heading (rad)", &e.heading_rad),
            ] {
                let _ = writeln!(
                    out,
                    "    {name:<14} {:>10.3} {:>10.3} {:>+10.3}",
                    a.median_abs, a.mean_abs, a.mean_signed
                );
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heading_modulo_pi() {
        assert!(heading_error_mod_pi(0.3 + PI, 0.3).abs() < 1e-12);
        assert!(heading_error_mod_pi(-PI, 0.0).abs() < 1e-12);
        assert!((heading_error_mod_pi(0.2, 0.0) - 0.2).abs() < 1e-12);
        assert!((heading_error_mod_pi(0.0, 0.2) + 0.2).abs() < 1e-12);
        assert!((heading_error_mod_pi(PI - 0.1, 0.0) + 0.1).abs() < 1e-12);
    }

    #[test]
    fn axis_statistics() {
        let a = axis_error(vec![0.5, -1.0, 2.0, -0.1]);
        assert!((a.median_abs - 0.75).abs() < 1e-12);
        assert!((a.mean_abs - 0.9).abs() < 1e-12);
        assert!((a.mean_signed - 0.35).abs() < 1e-12);
        assert_eq!(axis_error(vec![3.0]).median_abs, 3.0);
    }
}
