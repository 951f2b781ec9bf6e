//! REDB (Chen et al., "Revisiting Domain-Adaptive 3D Object Detection by Reliable, Diverse and
//! Class-balanced Pseudo-Labeling", ICCV 2023), as far as the paper describes it, simplified:
//!
//! - **Reliable** — the paper's cross-domain examination pastes a pseudo-labelled target object
//!   into a source scene and keeps it when the detector finds it again there. Here the
//!   examination is a second, transformed view of the same target frame (mirrored), mapped back:
//!   a pseudo-box is reliable when that view's detections hold a box of its class at 3D IoU ≥
//!   `reliable_iou`. It tests the same thing — does the detector's box survive a change of
//!   context — without a source scene to paste into.
//! - **Diverse** — the paper's overlapped-box counting favours boxes of under-represented
//!   geometry. Here each class's reliable boxes are binned by BEV range (0–20, 20–40, 40+ m) and
//!   points inside (≤ 20, 21–100, > 100); no bin keeps more than `max_bin_share` of the class's
//!   reliable boxes (the best-scoring kept), so dense near boxes cannot crowd out far sparse ones.
//! - **Class-balanced** — no class keeps more than `balance_ratio` × the rarest selected class's
//!   count (best-scoring first).
//!
//! Boxes not selected are not dropped but *ignored* in training (their anchors teach neither
//! way), because an unselected box is still likely an object.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RedbConfig {
    pub reliable_iou: f64,
    pub max_bin_share: f64,
    pub balance_ratio: f64,
}

impl Default for RedbConfig {
    fn default() -> Self {
        Self { reliable_iou: 0.5, max_bin_share: 0.5, balance_ratio: 2.0 }
    }
}

/// One positive pseudo-box, as the selection sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    pub class: usize,
    pub score: f64,
    /// Best 3D IoU with a same-class box of the examination view.
    pub examination_iou: f64,
    pub range_m: f64,
    pub points: usize,
}

/// The geometry bin of a candidate (range bin × points bin).
pub fn bin_of(c: &Candidate) -> (u8, u8) {
    let r = if c.range_m < 20.0 {
        0
    } else if c.range_m < 40.0 {
        1
    } else {
        2
    };
    let p = match c.points {
        0..=20 => 0,
        21..=100 => 1,
        _ => 2,
    };
    (r, p)
}

/// Which candidates are selected (same order as `candidates`).
pub fn select(candidates: &[Candidate], cfg: &RedbConfig) -> Vec<bool> {
    let mut keep: Vec<bool> = candidates.iter().map(|c| c.examination_iou >= cfg.reliable_iou).collect();
    let by_score = |ids: &mut Vec<usize>| {
        ids.sort_by(|&a, &b| candidates[b].score.total_cmp(&candidates[a].score).then(a.cmp(&b)))
    };
    // Diversity: cap each (class, bin) at a share of the class's reliable boxes.
    let mut classes: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (i, c) in candidates.iter().enumerate().filter(|(i, _)| keep[*i]) {
        classes.entry(c.class).or_default().push(i);
    }
    for ids in classes.values() {
        let cap = ((cfg.max_bin_share * ids.len() as f64).ceil() as usize).max(1);
        let mut bins: BTreeMap<(u8, u8), Vec<usize>> = BTreeMap::new();
        for &i in ids {
            bins.entry(bin_of(&candidates[i])).or_default().push(i);
        }
        for mut b in bins.into_values() {
            by_score(&mut b);
            b.iter().skip(cap).for_each(|&i| keep[i] = false);
        }
    }
    // Class balance: at most `balance_ratio` × the rarest class's selected count.
    let mut per_class: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (i, c) in candidates.iter().enumerate().filter(|(i, _)| keep[*i]) {
        per_class.entry(c.class).or_default().push(i);
    }
    if let Some(rarest) = per_class.values().map(Vec::len).min() {
        let cap = ((cfg.balance_ratio * rarest as f64).ceil() as usize).max(1);
        for mut ids in per_class.into_values() {
            by_score(&mut ids);
            ids.iter().skip(cap).for_each(|&i| keep[i] = false);
        }
    }
    keep
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(class: usize, score: f64, iou: f64, range_m: f64, points: usize) -> Candidate {
        Candidate { class, score, examination_iou: iou, range_m, points }
    }

    #[test]
    fn unreliable_boxes_are_not_selected() {
        let cands = vec![c(0, 0.9, 0.8, 10.0, 200), c(0, 0.9, 0.3, 30.0, 50)];
        assert_eq!(select(&cands, &RedbConfig { max_bin_share: 1.0, ..Default::default() }), vec![true, false]);
    }

    #[test]
    fn crowded_bins_are_capped_by_score() {
        // Four near dense cars and one far sparse car: with a 0.5 share the near bin keeps 3 of 4.
        let mut cands: Vec<Candidate> = (0..4).map(|k| c(0, 0.6 + 0.1 * k as f64, 0.9, 5.0, 500)).collect();
        cands.push(c(0, 0.55, 0.9, 45.0, 10));
        let keep = select(&cands, &RedbConfig { balance_ratio: 100.0, ..Default::default() });
        assert_eq!(keep, vec![false, true, true, true, true]);
    }

    #[test]
    fn classes_are_balanced() {
        // Six cars in six different bins, one pedestrian: the ratio 2 keeps the best two cars.
        let ranges = [5.0, 25.0, 45.0];
        let mut cands: Vec<Candidate> =
            (0..6).map(|k| c(0, 0.5 + 0.05 * k as f64, 0.9, ranges[k % 3], if k < 3 { 10 } else { 50 })).collect();
        cands.push(c(1, 0.7, 0.9, 10.0, 30));
        let keep = select(&cands, &RedbConfig { max_bin_share: 1.0, ..Default::default() });
        assert_eq!(keep, vec![false, false, false, false, true, true, true]);
        assert!(select(&[], &RedbConfig::default()).is_empty());
    }
}
