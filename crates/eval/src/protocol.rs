//! The protocol over a split: the reference's `get_official_eval_result` / `do_eval` /
//! `eval_class`, with rayon over frames and no pair of boxes from different frames.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::anno::KittiFrame;
use crate::ap::{ap_r11, ap_r40, curves, get_thresholds, PrCounts, N_SAMPLE_PTS};
use crate::classes::Overlaps;
use crate::error::EvalError;
use crate::matching::{Pass, Scratch};
use crate::prepare::PreparedFrame;

/// A class to evaluate and its minimum overlaps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassSpec {
    pub name: String,
    pub overlaps: Overlaps,
}

/// AP at easy / moderate / hard, in percent. NaN (0/0 precision, as numpy gives) is written
/// to JSON as `null` and read back as NaN.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MetricAp {
    #[serde(with = "nan_as_null")]
    pub r11: [f64; 3],
    #[serde(with = "nan_as_null")]
    pub r40: [f64; 3],
}

mod nan_as_null {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(v: &[f64; 3], s: S) -> Result<S::Ok, S::Error> {
        v.map(|x| (!x.is_nan()).then_some(x)).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
        Ok(<[Option<f64>; 3]>::deserialize(d)?.map(|x| x.unwrap_or(f64::NAN)))
    }
}

/// Results of one overlap set (strict or loose) of one class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetResult {
    /// `[bbox, bev, 3d]`.
    pub min_overlaps: [f64; 3],
    pub bbox: MetricAp,
    pub bev: MetricAp,
    #[serde(rename = "3d")]
    pub d3: MetricAp,
    /// Present when orientation similarity was computed (detections carry alpha).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aos: Option<MetricAp>,
}

impl SetResult {
    pub fn metric(&self, m: usize) -> &MetricAp {
        match m {
            0 => &self.bbox,
            1 => &self.bev,
            _ => &self.d3,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassResult {
    pub class: String,
    /// Ground truths that count (not ignored) at easy / moderate / hard.
    pub num_gt: [usize; 3],
    /// Detections of this class.
    pub num_det: usize,
    /// `[strict, loose]`.
    pub sets: Vec<SetResult>,
}

/// The evaluation of one group of frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupResult {
    pub name: String,
    pub num_frames: usize,
    pub compute_aos: bool,
    pub classes: Vec<ClassResult>,
}

/// One (class, difficulty, metric, min_overlap) evaluation; duplicates share one.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Combo {
    class: usize,
    difficulty: usize,
    metric: usize,
    min_overlap: f64,
}

fn pass<'a>(f: &'a PreparedFrame, k: &Combo) -> Pass<'a> {
    Pass { frame: f, states: &f.states[k.class][k.difficulty], metric: k.metric, min_overlap: k.min_overlap }
}

/// Evaluates aligned ground-truth / detection frames exactly as the reference does.
/// `compute_aos` follows OpenPCDet: on when the first non-empty detection frame's first alpha
/// is not −10 (see [`default_compute_aos`]).
pub fn evaluate_kitti(
    name: &str,
    gt: &[KittiFrame],
    dt: &[KittiFrame],
    classes: &[ClassSpec],
    compute_aos: bool,
) -> Result<GroupResult, EvalError> {
    if gt.len() != dt.len() {
        return Err(EvalError::Input(format!("{} ground-truth frames but {} detection frames", gt.len(), dt.len())));
    }
    for c in classes {
        for v in c.overlaps.strict.iter().chain(&c.overlaps.loose) {
            if !(0.0..=1.0).contains(v) {
                return Err(EvalError::Option(format!("class {}: min overlap {v} is not in [0, 1]", c.name)));
            }
        }
    }
    check_finite(gt, dt)?;
    let classes_lc: Vec<String> = classes.iter().map(|c| c.name.to_lowercase()).collect();
    let frames: Vec<PreparedFrame> =
        gt.par_iter().zip(dt.par_iter()).map(|(g, d)| PreparedFrame::new(g, d, &classes_lc)).collect();

    // Difficulties whose states are identical in every frame (all of them for datasets with the
    // fake KITTI fields) are evaluated once.
    let mut diff_source = vec![[0usize, 1, 2]; classes.len()];
    for (c, src) in diff_source.iter_mut().enumerate() {
        for d in 1..3 {
            if let Some(e) =
                (0..d).find(|&e| src[e] == e && frames.par_iter().all(|f| f.states[c][d] == f.states[c][e]))
            {
                src[d] = e;
            }
        }
    }
    let mut combos: Vec<Combo> = Vec::new();
    // index[class][difficulty][set][metric] → combo
    let mut index = vec![[[[0usize; 3]; 2]; 3]; classes.len()];
    for (c, spec) in classes.iter().enumerate() {
        for d in 0..3 {
            for (s, set) in spec.overlaps.sets().iter().enumerate() {
                for (m, &min_overlap) in set.iter().enumerate() {
                    let combo = Combo { class: c, difficulty: diff_source[c][d], metric: m, min_overlap };
                    index[c][d][s][m] = combos.iter().position(|x| *x == combo).unwrap_or_else(|| {
                        combos.push(combo);
                        combos.len() - 1
                    });
                }
            }
        }
    }

    // Threshold pass: TP scores per combo.
    let n = combos.len();
    let mut tp_scores: Vec<Vec<f64>> = frames
        .par_iter()
        .fold(
            || (vec![Vec::new(); n], Scratch::default()),
            |(mut acc, mut scratch), f| {
                for (k, out) in combos.iter().zip(acc.iter_mut()) {
                    pass(f, k).tp_scores(&mut scratch, out);
                }
                (acc, scratch)
            },
        )
        .map(|(acc, _)| acc)
        .reduce(
            || vec![Vec::new(); n],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    x.extend(y);
                }
                a
            },
        );

    let num_valid_gt: Vec<[usize; 3]> = (0..classes.len())
        .map(|c| std::array::from_fn(|d| frames.par_iter().map(|f| f.states[c][d].num_valid_gt).sum()))
        .collect();
    let thresholds: Vec<Vec<f64>> = combos
        .iter()
        .zip(tp_scores.iter_mut())
        .map(|(k, s)| get_thresholds(s, num_valid_gt[k.class][k.difficulty]))
        .collect();

    // PR pass.
    let empty = || vec![[PrCounts::default(); N_SAMPLE_PTS]; n];
    let pr: Vec<[PrCounts; N_SAMPLE_PTS]> = frames
        .par_iter()
        .fold(
            || (empty(), Scratch::default()),
            |(mut acc, mut scratch), f| {
                for ((k, t), a) in combos.iter().zip(&thresholds).zip(acc.iter_mut()) {
                    pass(f, k).accumulate(t, &mut scratch, a);
                }
                (acc, scratch)
            },
        )
        .map(|(acc, _)| acc)
        .reduce(empty, |mut a, b| {
            for (x, y) in a.iter_mut().zip(b) {
                for (p, q) in x.iter_mut().zip(y) {
                    p.tp += q.tp;
                    p.fp += q.fp;
                    p.fn_ += q.fn_;
                    p.similarity += q.similarity;
                }
            }
            a
        });

    let curves: Vec<_> = pr.iter().zip(&thresholds).map(|(p, t)| curves(&p[..t.len()])).collect();
    let num_dt: Vec<usize> = (0..classes.len()).map(|c| frames.iter().map(|f| f.num_dt[c]).sum()).collect();
    let results = classes
        .iter()
        .enumerate()
        .map(|(c, spec)| {
            let sets = spec
                .overlaps
                .sets()
                .iter()
                .enumerate()
                .map(|(s, set)| {
                    let ap = |m: usize, aos: bool| {
                        let p = |d: usize| {
                            let cv = &curves[index[c][d][s][m]];
                            if aos {
                                &cv.aos
                            } else {
                                &cv.precision
                            }
                        };
                        MetricAp {
                            r11: std::array::from_fn(|d| ap_r11(p(d))),
                            r40: std::array::from_fn(|d| ap_r40(p(d))),
                        }
                    };
                    SetResult {
                        min_overlaps: *set,
                        bbox: ap(0, false),
                        bev: ap(1, false),
                        d3: ap(2, false),
                        aos: compute_aos.then(|| ap(0, true)),
                    }
                })
                .collect();
            ClassResult { class: spec.name.clone(), num_gt: num_valid_gt[c], num_det: num_dt[c], sets }
        })
        .collect();
    Ok(GroupResult { name: name.to_string(), num_frames: gt.len(), compute_aos, classes: results })
}

/// Every number of every object must be finite (the passes compare and sort them).
pub(crate) fn check_finite(gt: &[KittiFrame], dt: &[KittiFrame]) -> Result<(), EvalError> {
    for (what, frames) in [("ground truth", gt), ("detection", dt)] {
        for (f, frame) in frames.iter().enumerate() {
            let bad = frame.objects.iter().find(|o| {
                ![o.truncated, o.occluded, o.alpha, o.rotation_y, o.score]
                    .iter()
                    .chain(&o.bbox)
                    .chain(&o.dimensions)
                    .chain(&o.location)
                    .all(|v| v.is_finite())
            });
            if let Some(o) = bad {
                return Err(EvalError::Input(format!(
                    "{what} frame {f} ({}): {} has a non-finite value",
                    frame.id, o.name
                )));
            }
        }
    }
    Ok(())
}

/// OpenPCDet's rule for AOS: the first detection frame with any detection decides, by whether
/// its first alpha is a real angle (−10 marks "unknown").
pub fn default_compute_aos(dt: &[KittiFrame]) -> bool {
    dt.iter().find_map(|f| f.objects.first()).is_some_and(|o| o.alpha != -10.0)
}
