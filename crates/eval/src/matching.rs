//! The reference's `compute_statistics_jit` for one frame: the threshold pass (collects the
//! scores of true positives) and the precision/recall pass at every score threshold.
//!
//! Rules kept exactly: overlap must be strictly greater than `min_overlap`; ground truths are
//! visited in index order and take, in the threshold pass, the highest-scoring free detection,
//! in the PR pass the free valid detection of largest overlap (first index on ties), falling
//! back to an ignored detection only while no valid one was seen; ignored ground truths and
//! ignored detections consume their match without counting; detections of another class take no
//! part; for the bbox metric, unmatched detections inside DontCare regions are not false
//! positives.
//!
//! Speed: candidate pairs come from the sparse overlaps, and in the PR pass the matching is only
//! recomputed when the set of active (score ≥ threshold) detections that can matter changes; in
//! between only the false-positive count moves, which is a count of active valid detections.
//! When a frame's overlaps are one value for every pair (the 2D metric with the fake 50 px
//! boxes), the scans above pick detections in a fixed order, which is followed directly.

use crate::ap::PrCounts;
use crate::prepare::{PreparedFrame, States};

/// The reference's `NO_DETECTION`: a detection needs a score above it to be taken.
const NO_DETECTION: f64 = -10_000_000.0;

pub(crate) struct Pass<'a> {
    pub frame: &'a PreparedFrame,
    pub states: &'a States,
    pub metric: usize,
    pub min_overlap: f64,
}

/// Reusable per-thread buffers.
#[derive(Default)]
pub(crate) struct Scratch {
    assigned: Vec<bool>,
    relevant: Vec<f64>,
    valid: Vec<f64>,
    seen: Vec<bool>,
    order: Vec<usize>,
    order_ignored: Vec<usize>,
}

impl Pass<'_> {
    /// `Some(true)`: every GT–detection pair of the frame overlaps by the same value, above the
    /// threshold; `Some(false)`: the same value, not above it; `None`: overlaps differ.
    fn uniform_hit(&self) -> Option<bool> {
        self.frame.uniform[self.metric].map(|v| v > self.min_overlap)
    }

    /// Threshold pass (`compute_fp=False`): appends the scores of true positives to `out`.
    pub fn tp_scores(&self, scratch: &mut Scratch, out: &mut Vec<f64>) {
        let (gt, dt, score) = (&self.states.gt, &self.states.dt, &self.frame.dt_score);
        match self.uniform_hit() {
            Some(false) => return,
            Some(true) => {
                // Each GT takes the best-scoring free detection, the first on ties.
                let order = &mut scratch.order;
                order.clear();
                order.extend((0..dt.len()).filter(|&j| dt[j] != -1 && score[j] > NO_DETECTION));
                order.sort_by(|&a, &b| score[b].total_cmp(&score[a]).then(a.cmp(&b)));
                let mut next = order.iter();
                for &g in gt.iter().filter(|&&g| g != -1) {
                    let Some(&j) = next.next() else { break };
                    if g != 1 && dt[j] != 1 {
                        out.push(score[j]);
                    }
                }
                return;
            }
            None => {}
        }
        let assigned = &mut scratch.assigned;
        assigned.clear();
        assigned.resize(dt.len(), false);
        let rows = &self.frame.overlaps[self.metric];
        for (i, &g) in gt.iter().enumerate() {
            if g == -1 {
                continue;
            }
            let mut det = None;
            let mut best = NO_DETECTION;
            for &(j, ov) in rows.row(i) {
                let j = j as usize;
                if dt[j] == -1 || assigned[j] {
                    continue;
                }
                if ov > self.min_overlap && score[j] > best {
                    det = Some(j);
                    best = score[j];
                }
            }
            if let Some(j) = det {
                assigned[j] = true;
                if g != 1 && dt[j] != 1 {
                    out.push(score[j]);
                }
            }
        }
    }

    /// PR pass (`compute_fp=True`) at every threshold (non-increasing), added into `acc`.
    pub fn accumulate(&self, thresholds: &[f64], scratch: &mut Scratch, acc: &mut [PrCounts]) {
        if thresholds.is_empty() {
            return;
        }
        let (gt, dt, score) = (&self.states.gt, &self.states.dt, &self.frame.dt_score);
        // Detections whose activity can change the matching: candidates of some GT, and valid
        // detections inside a DontCare region (bbox metric only).
        let seen = &mut scratch.seen;
        seen.clear();
        seen.resize(dt.len(), false);
        let relevant = &mut scratch.relevant;
        relevant.clear();
        let rows = &self.frame.overlaps[self.metric];
        match self.uniform_hit() {
            Some(true) if gt.iter().any(|&g| g != -1) => {
                for j in (0..dt.len()).filter(|&j| dt[j] != -1) {
                    seen[j] = true;
                    relevant.push(score[j]);
                }
            }
            Some(_) => {}
            None => {
                for (i, &g) in gt.iter().enumerate() {
                    if g == -1 {
                        continue;
                    }
                    for &(j, ov) in rows.row(i) {
                        let j = j as usize;
                        if dt[j] != -1 && ov > self.min_overlap && !seen[j] {
                            seen[j] = true;
                            relevant.push(score[j]);
                        }
                    }
                }
            }
        }
        if self.metric == 0 {
            for r in 0..self.frame.dontcare.rows() {
                for &(j, ov) in self.frame.dontcare.row(r) {
                    let j = j as usize;
                    if dt[j] == 0 && ov > self.min_overlap && !seen[j] {
                        seen[j] = true;
                        relevant.push(score[j]);
                    }
                }
            }
        }
        let valid = &mut scratch.valid;
        valid.clear();
        valid.extend(dt.iter().zip(score).filter(|(&s, _)| s == 0).map(|(_, &sc)| sc));
        if relevant.is_empty() && valid.is_empty() && !gt.contains(&0) {
            return;
        }
        relevant.sort_unstable_by(|a, b| b.total_cmp(a));
        valid.sort_unstable_by(|a, b| b.total_cmp(a));

        let (mut n_rel, mut n_valid) = (0usize, 0usize);
        let mut last_rel = usize::MAX;
        let mut m = Matched::default();
        for (k, &t) in thresholds.iter().enumerate() {
            while n_rel < relevant.len() && relevant[n_rel] >= t {
                n_rel += 1;
            }
            while n_valid < valid.len() && valid[n_valid] >= t {
                n_valid += 1;
            }
            if n_rel != last_rel {
                m = self.match_at(t, &mut scratch.assigned, &mut scratch.order, &mut scratch.order_ignored);
                last_rel = n_rel;
            }
            let fp = (n_valid - m.assigned_valid - m.dontcare) as u64;
            let a = &mut acc[k];
            a.tp += m.tp;
            a.fp += fp;
            a.fn_ += m.fn_;
            // The reference adds similarity −1 as "nothing" when there is neither TP nor FP.
            if m.tp > 0 || fp > 0 {
                a.similarity += m.similarity;
            }
        }
    }

    fn match_at(&self, t: f64, assigned: &mut Vec<bool>, valid: &mut Vec<usize>, ignored: &mut Vec<usize>) -> Matched {
        let (gt, dt, score) = (&self.states.gt, &self.states.dt, &self.frame.dt_score);
        assigned.clear();
        assigned.resize(dt.len(), false);
        let mut out = Matched::default();
        let mut visit = |i: usize, g: i8, det: Option<usize>| match det {
            Some(j) => self.count(g, i, j, &mut out),
            None if g == 0 => out.fn_ += 1,
            None => {}
        };
        match self.uniform_hit() {
            Some(true) => self.match_uniform(t, assigned, valid, ignored, &mut visit),
            Some(false) => gt.iter().enumerate().filter(|(_, &g)| g != -1).for_each(|(i, &g)| visit(i, g, None)),
            None => self.match_sparse(t, assigned, &mut visit),
        }
        out.assigned_valid = assigned.iter().zip(dt).filter(|(&a, &s)| a && s == 0).count();
        if self.metric == 0 {
            for r in 0..self.frame.dontcare.rows() {
                for &(j, ov) in self.frame.dontcare.row(r) {
                    let j = j as usize;
                    if assigned[j] || dt[j] != 0 || score[j] < t {
                        continue;
                    }
                    if ov > self.min_overlap {
                        assigned[j] = true;
                        out.dontcare += 1;
                    }
                }
            }
        }
        out
    }

    /// The PR pass's matching at score threshold `t`, per ground truth: the detection it took
    /// (valid or ignored), `None` when it took none or takes no part (state −1). What the error
    /// breakdown reads recall and misses from, so that they follow the protocol's matching.
    pub fn assignment(&self, t: f64) -> Vec<Option<usize>> {
        let (gt, dt) = (&self.states.gt, &self.states.dt);
        let mut out = vec![None; gt.len()];
        let mut assigned = vec![false; dt.len()];
        let mut visit = |i: usize, _g: i8, det: Option<usize>| out[i] = det;
        match self.uniform_hit() {
            Some(true) => self.match_uniform(t, &mut assigned, &mut Vec::new(), &mut Vec::new(), &mut visit),
            Some(false) => {}
            None => self.match_sparse(t, &mut assigned, &mut visit),
        }
        out
    }

    fn count(&self, g: i8, i: usize, j: usize, out: &mut Matched) {
        if g == 1 || self.states.dt[j] == 1 {
            return;
        }
        out.tp += 1;
        let delta = self.frame.gt_alpha[i] - self.frame.dt_alpha[j];
        out.similarity += (1.0 + delta.cos()) / 2.0;
    }

    /// With equal overlaps everywhere, each GT's scan keeps the first free valid detection, or
    /// failing one the first free ignored detection: both are taken in index order.
    fn match_uniform(
        &self,
        t: f64,
        assigned: &mut [bool],
        valid: &mut Vec<usize>,
        ignored: &mut Vec<usize>,
        visit: &mut impl FnMut(usize, i8, Option<usize>),
    ) {
        let (gt, dt, score) = (&self.states.gt, &self.states.dt, &self.frame.dt_score);
        valid.clear();
        ignored.clear();
        for j in 0..dt.len() {
            if score[j] >= t {
                match dt[j] {
                    0 => valid.push(j),
                    1 => ignored.push(j),
                    _ => {}
                }
            }
        }
        let (mut v, mut ig) = (valid.iter(), ignored.iter());
        for (i, &g) in gt.iter().enumerate() {
            if g == -1 {
                continue;
            }
            let det = v.next().or_else(|| ig.next()).copied();
            if let Some(j) = det {
                assigned[j] = true;
            }
            visit(i, g, det);
        }
    }

    fn match_sparse(&self, t: f64, assigned: &mut [bool], visit: &mut impl FnMut(usize, i8, Option<usize>)) {
        let (gt, dt, score) = (&self.states.gt, &self.states.dt, &self.frame.dt_score);
        let rows = &self.frame.overlaps[self.metric];
        for (i, &g) in gt.iter().enumerate() {
            if g == -1 {
                continue;
            }
            let mut det = None;
            let mut max_overlap = 0.0;
            let mut took_ignored = false;
            for &(j, ov) in rows.row(i) {
                let j = j as usize;
                if dt[j] == -1 || assigned[j] || score[j] < t || ov <= self.min_overlap {
                    continue;
                }
                if (ov > max_overlap || took_ignored) && dt[j] == 0 {
                    max_overlap = ov;
                    det = Some(j);
                    took_ignored = false;
                } else if det.is_none() && dt[j] == 1 {
                    det = Some(j);
                    took_ignored = true;
                }
            }
            if let Some(j) = det {
                assigned[j] = true;
            }
            visit(i, g, det);
        }
    }
}

/// The matching at one threshold, independent of detections that cannot match.
#[derive(Debug, Default, Clone, Copy)]
struct Matched {
    tp: u64,
    fn_: u64,
    /// Valid detections consumed by a GT (TP or ignored GT).
    assigned_valid: usize,
    /// Valid unmatched detections inside DontCare regions.
    dontcare: usize,
    similarity: f64,
}
