//! The adaptation's guard (issue 47): Knowledge-Adaptation must not leave the detector worse on
//! its target than it found it, and without target labels nothing measures that directly. Two
//! label-free checks, both in `adapt.json` and printed:
//!
//! - **positives per frame** ([`PositiveStats`]): how many positive pseudo-labels KA has to learn
//!   from, the mean per target frame and the frames without any; below
//!   `warn_positives_per_frame` the run warns that the target gives too little to adapt on.
//! - **adapted vs PA through VPP** ([`Comparison`]): both models on (up to `max_frames` of) the
//!   target's training frames through VPP. The PA model through VPP is what adaptation starts
//!   from and is already a usable detector on the target; an adapted model that no longer finds
//!   what it found has collapsed (KA taught it the target is empty). `retained` is the share of
//!   the PA model's confident boxes (score ≥ `score`) that the adapted model still reports (any
//!   score, same class, BEV IoU ≥ `match_iou`); below `min_retention` the guard ships the PA
//!   model through VPP, otherwise the adapted one. Both checkpoints are kept either way.
//!
//! Retention rather than agreement decides: adaptation is meant to find more than the PA model
//! did, which lowers agreement (F1, reported beside it) without being a failure, while losing
//! most of what the PA model found is the failure this guards against.

use std::path::PathBuf;

use pi3det_geometry::iou::bev_iou;
use serde::{Deserialize, Serialize};

use pi3det_nn::detect::FrameDetections;
use pi3det_nn::error::{NnError, Result};

/// `[guard]` of an adaptation config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuardConfig {
    /// Warn when the positive pseudo-labels per target frame are fewer than this.
    pub warn_positives_per_frame: f64,
    /// Compare the adapted model with the PA model through VPP after KA (one more inference
    /// pass of the adapted model over the compared frames).
    pub compare: bool,
    /// Compare on at most this many target training frames, spread evenly (0: all).
    pub max_frames: usize,
    /// Confident detections score at least this; absent: the pseudo-labels' `ignore_score`.
    pub score: Option<f64>,
    /// Two boxes are the same object at this BEV IoU (same class).
    pub match_iou: f64,
    /// Ship the adapted model when it still finds at least this share of the PA model's
    /// confident boxes.
    pub min_retention: f64,
}

impl Default for GuardConfig {
    fn default() -> Self {
        Self {
            warn_positives_per_frame: 0.25,
            compare: true,
            max_frames: 64,
            score: None,
            match_iou: 0.3,
            min_retention: 0.5,
        }
    }
}

impl GuardConfig {
    pub fn validate(&self) -> Result<()> {
        let unit = |v: f64| (0.0..=1.0).contains(&v);
        let ok = self.warn_positives_per_frame.is_finite()
            && self.warn_positives_per_frame >= 0.0
            && self.score.is_none_or(|s| (0.0..1.0).contains(&s))
            && unit(self.match_iou)
            && self.match_iou > 0.0
            && unit(self.min_retention);
        if ok {
            Ok(())
        } else {
            Err(NnError::config("guard", format!(
                "guard: need warn_positives_per_frame ≥ 0, score in [0, 1), match_iou in (0, 1] and min_retention in [0, 1] (got {self:?})"
            )))
        }
    }
}

/// Positive pseudo-labels (score ≥ `positive_score`) over the target frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct PositiveStats {
    pub frames: usize,
    pub positives: usize,
    pub per_frame: f64,
    pub frames_without: usize,
}

impl PositiveStats {
    pub fn of(labels: &[FrameDetections], positive_score: f64) -> Self {
        let counts: Vec<usize> = labels
            .iter()
            .map(|f| f.objects.iter().filter(|o| o.score.unwrap_or(1.0) >= positive_score).count())
            .collect();
        let positives: usize = counts.iter().sum();
        Self {
            frames: labels.len(),
            positives,
            per_frame: positives as f64 / labels.len().max(1) as f64,
            frames_without: counts.iter().filter(|&&c| c == 0).count(),
        }
    }

    /// The warning when these are too few to adapt on (`min` per frame).
    /// The warning when the positives per frame are fewer than `min`; `rules`: whether KA's
    /// background rules are on (what the warning can promise depends on them).
    pub fn warning(&self, min: f64, rules: bool) -> Option<String> {
        (self.per_frame < min).then(|| {
            let then = if rules {
                "KA's background rules keep it from unlearning the target"
            } else {
                "with [target_negatives] off, KA may teach the detector that the target is empty"
            };
            format!(
                "only {:.2} positive pseudo-labels per target frame ({} in {} frames, {} frames without any; the guard warns below {min}): too few to adapt on — {then}; compare the adapted model with the PA model through VPP (the guard does when [guard] compare is on)",
                self.per_frame, self.positives, self.frames, self.frames_without
            )
        })
    }
}

/// One model's confident detections on the compared frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct ModelSignal {
    pub detections: usize,
    pub per_frame: f64,
    /// Mean score of the confident detections (0 without any).
    pub mean_score: f64,
}

/// Which model the guard would ship.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Ship {
    Adapted,
    PaVpp,
}

impl std::fmt::Display for Ship {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Ship::Adapted => "adapted",
            Ship::PaVpp => "pa_vpp",
        })
    }
}

/// The label-free comparison of the adapted model with the PA model through VPP.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    pub frames: usize,
    /// The score confident detections reach.
    pub score: f64,
    pub pa_vpp: ModelSignal,
    pub adapted: ModelSignal,
    /// Share of the PA model's confident boxes the adapted model still reports (1 when the PA
    /// model has none).
    pub retained: f64,
    /// F1 of the two models' confident boxes matched one-to-one.
    pub agreement_f1: f64,
    pub ship: Ship,
    pub reason: String,
    /// The checkpoint to ship (the PA checkpoint runs through VPP, as `adapt` evaluates it).
    pub ship_checkpoint: PathBuf,
    pub pa_checkpoint: PathBuf,
    pub adapted_checkpoint: PathBuf,
}

fn signal(frames: &[FrameDetections], score: f64) -> ModelSignal {
    // A box without a score counts as certain, as in `matches`.
    let s: Vec<f64> =
        frames.iter().flat_map(|f| &f.objects).map(|o| o.score.unwrap_or(1.0)).filter(|&s| s >= score).collect();
    ModelSignal {
        detections: s.len(),
        per_frame: s.len() as f64 / frames.len().max(1) as f64,
        mean_score: if s.is_empty() { 0.0 } else { s.iter().sum::<f64>() / s.len() as f64 },
    }
}

/// Matches of `a`'s boxes scoring ≥ `a_score` to `b`'s scoring ≥ `b_score`, one-to-one, greedy
/// by `a`'s score, same class, BEV IoU ≥ `iou` (BEV, not the 3-D IoU of
/// `pi3det_autolabel::quality`: a model's z and height on a levelled frame are what adaptation
/// changes most, and a box found in a wrong z is still found).
fn matches(a: &FrameDetections, b: &FrameDetections, a_score: f64, b_score: f64, iou: f64) -> usize {
    let score = |o: &pi3det_data::Object| o.score.unwrap_or(1.0);
    let mut av: Vec<_> = a.objects.iter().filter(|o| score(o) >= a_score).collect();
    av.sort_by(|x, y| score(y).total_cmp(&score(x)));
    let bv: Vec<_> = b.objects.iter().filter(|o| score(o) >= b_score).collect();
    let mut taken = vec![false; bv.len()];
    let mut n = 0;
    for o in &av {
        let best = bv
            .iter()
            .enumerate()
            .filter(|(j, p)| !taken[*j] && p.name == o.name)
            .map(|(j, p)| (j, bev_iou(&o.box3d, &p.box3d)))
            .filter(|&(_, v)| v >= iou)
            .max_by(|x, y| x.1.total_cmp(&y.1));
        if let Some((j, _)) = best {
            taken[j] = true;
            n += 1;
        }
    }
    n
}

/// Compares the adapted model's detections with the PA model's (through VPP) on the same
/// frames, in the same order, and decides which to ship.
pub fn compare(
    pa_vpp: &[FrameDetections],
    adapted: &[FrameDetections],
    cfg: &GuardConfig,
    score: f64,
    pa_checkpoint: PathBuf,
    adapted_checkpoint: PathBuf,
) -> Result<Comparison> {
    if pa_vpp.len() != adapted.len() {
        return Err(NnError::Input(format!(
            "guard: {} frames of the PA model against {} of the adapted one",
            pa_vpp.len(),
            adapted.len()
        )));
    }
    let (pa_signal, adapted_signal) = (signal(pa_vpp, score), signal(adapted, score));
    let (mut kept, mut both) = (0, 0);
    for (p, a) in pa_vpp.iter().zip(adapted) {
        kept += matches(p, a, score, 0.0, cfg.match_iou);
        both += matches(p, a, score, score, cfg.match_iou);
    }
    let (pa_n, ad_n) = (pa_signal.detections, adapted_signal.detections);
    let retained = if pa_n == 0 { 1.0 } else { kept as f64 / pa_n as f64 };
    let agreement_f1 = if pa_n + ad_n == 0 { 1.0 } else { 2.0 * both as f64 / (pa_n + ad_n) as f64 };
    let (ship, reason) = if pa_n == 0 {
        (Ship::Adapted, "the PA model through VPP made no confident detection on these frames: nothing to lose".into())
    } else if retained < cfg.min_retention {
        (
            Ship::PaVpp,
            format!(
                "the adapted model still finds {:.0} % of the PA model's {pa_n} confident boxes (< {:.0} %): KA unlearnt the target; ship the PA model through VPP",
                100.0 * retained,
                100.0 * cfg.min_retention
            ),
        )
    } else {
        (
            Ship::Adapted,
            format!(
                "the adapted model still finds {:.0} % of the PA model's {pa_n} confident boxes (≥ {:.0} %)",
                100.0 * retained,
                100.0 * cfg.min_retention
            ),
        )
    };
    let ship_checkpoint = match ship {
        Ship::Adapted => adapted_checkpoint.clone(),
        Ship::PaVpp => pa_checkpoint.clone(),
    };
    Ok(Comparison {
        frames: pa_vpp.len(),
        score,
        pa_vpp: pa_signal,
        adapted: adapted_signal,
        retained,
        agreement_f1,
        ship,
        reason,
        ship_checkpoint,
        pa_checkpoint,
        adapted_checkpoint,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::{FrameInfo, Object};
    use pi3det_geometry::Box3d;

    fn frame(boxes: &[(f64, f64)]) -> FrameDetections {
        FrameDetections {
            info: FrameInfo::new("0", "x.bin".into()),
            objects: boxes
                .iter()
                .map(|&(x, s)| Object {
                    score: Some(s),
                    ..Object::new("Car", Box3d::new(x, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0))
                })
                .collect(),
        }
    }

    #[test]
    fn positives_per_frame_and_the_warning() {
        let labels = vec![frame(&[(0.0, 0.9), (10.0, 0.3)]), frame(&[(0.0, 0.3)]), frame(&[])];
        let s = PositiveStats::of(&labels, 0.5);
        assert_eq!((s.frames, s.positives, s.frames_without), (3, 1, 2));
        assert!(s.warning(0.25, true).is_none());
        assert!(s.warning(0.5, true).unwrap().contains("0.33 positive pseudo-labels per target frame"));
        assert!(s.warning(0.5, false).unwrap().contains("may teach the detector that the target is empty"));
    }

    #[test]
    fn a_collapsed_model_ships_the_pa_model() {
        let pa = vec![frame(&[(0.0, 0.4), (10.0, 0.3), (20.0, 0.1)]), frame(&[(0.0, 0.25)])];
        let cfg = GuardConfig::default();
        let (p, a) = (PathBuf::from("pa.safetensors"), PathBuf::from("ka.safetensors"));
        // Collapsed: nothing left but one faint box.
        let gone = vec![frame(&[(0.3, 0.06)]), frame(&[])];
        let c = compare(&pa, &gone, &cfg, 0.2, p.clone(), a.clone()).unwrap();
        assert_eq!(c.pa_vpp.detections, 3, "confident: score ≥ 0.2");
        assert!((c.retained - 1.0 / 3.0).abs() < 1e-12, "a faint box still counts as found");
        assert_eq!((c.ship, c.ship_checkpoint.clone()), (Ship::PaVpp, p.clone()));
        assert_eq!((c.adapted.detections, c.agreement_f1), (0, 0.0));
        // Kept and extended: the adapted model ships, agreement below 1 because it finds more.
        let more = vec![frame(&[(0.2, 0.5), (10.1, 0.6), (30.0, 0.7)]), frame(&[(0.0, 0.3), (40.0, 0.5)])];
        let c = compare(&pa, &more, &cfg, 0.2, p.clone(), a.clone()).unwrap();
        assert_eq!((c.ship, c.retained), (Ship::Adapted, 1.0));
        assert!((c.agreement_f1 - 6.0 / 8.0).abs() < 1e-12, "{}", c.agreement_f1);
        assert_eq!(c.ship_checkpoint, a);
        assert!(compare(&pa, &more[..1], &cfg, 0.2, p, a).is_err());
    }
}
