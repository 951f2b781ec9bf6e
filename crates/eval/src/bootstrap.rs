//! Is one detector better than another on this data, or within noise? A paired bootstrap over
//! the validation split's sequences (the sequence, not the frame, is the unit: the frames of one
//! sequence share their scene and its objects).
//!
//! A draw picks as many sequences as the split has, with replacement; both detection sets are
//! evaluated on the same draw (paired), and AP is recomputed on the drawn frames, since AP does
//! not add over sequences. The interval is the 2.5 / 97.5 % percentile of the draws'
//! differences; an ordering is *resolved* when the interval excludes 0. `pi3det eval --baseline`
//! prints it per class, the benchmark's table per row against source-only, and `pi3det adapt`
//! for the adapted model against the pre-adapted one through VPP.

use std::collections::BTreeMap;

use pi3det_data::FrameInfo;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::detections::{Detection, Detections};
use crate::error::EvalError;
use crate::options::EvalOptions;
use crate::run::{evaluate, EvalReport};
use crate::summary::{summarize, ApSummary};

/// A difference (row − reference) and its bootstrap interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    /// On the full validation split.
    pub diff: f64,
    pub lo: f64,
    pub hi: f64,
    /// Draws the interval is made of (those with a finite difference).
    pub resamples: usize,
}

impl Interval {
    /// The interval excludes 0: the sign of the difference is resolved.
    pub fn resolved(&self) -> bool {
        self.lo > 0.0 || self.hi < 0.0
    }

    /// `+1.2 [−0.4, +2.9] within noise` / `… resolved`.
    pub fn describe(&self) -> String {
        if self.resamples == 0 {
            return format!("{:+.1} (no interval)", self.diff);
        }
        let verdict = if self.resolved() { "resolved" } else { "within noise" };
        format!("{:+.1} [{:+.1}, {:+.1}] {verdict}", self.diff, self.lo, self.hi)
    }
}

/// The 2.5 / 97.5 % percentiles (linear between order statistics).
fn percentiles_95(samples: &mut [f64]) -> (f64, f64) {
    samples.sort_by(f64::total_cmp);
    let q = |p: f64| {
        let x = p * (samples.len() - 1) as f64;
        let (i, f) = (x.floor() as usize, x.fract());
        let j = (i + 1).min(samples.len() - 1);
        samples[i] * (1.0 - f) + samples[j] * f
    };
    (q(0.025), q(0.975))
}

/// The draws of a paired bootstrap over groups: `groups[u]` is the number of groups (sequences)
/// of unit `u` (e.g. a seed's split); each draw holds, per unit, as many group indices drawn with
/// replacement. The first draw is the identity (the full splits).
pub fn draws(groups: &[usize], resamples: usize, seed: u64) -> Vec<Vec<Vec<usize>>> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut out = vec![groups.iter().map(|&n| (0..n).collect()).collect()];
    for _ in 0..resamples {
        out.push(groups.iter().map(|&n| (0..n).map(|_| rng.random_range(0..n)).collect()).collect());
    }
    out
}

/// The interval of `diffs`, one per draw of [`draws`] (the first on the full splits); draws
/// whose difference is not finite (no ground truth drawn) are left out.
pub fn interval(diffs: &[f64]) -> Interval {
    let full = diffs.first().copied().unwrap_or(f64::NAN);
    let mut samples: Vec<f64> = diffs.iter().skip(1).copied().filter(|d| d.is_finite()).collect();
    if samples.is_empty() {
        return Interval { diff: full, lo: f64::NAN, hi: f64::NAN, resamples: 0 };
    }
    let (lo, hi) = percentiles_95(&mut samples);
    Interval { diff: full, lo, hi, resamples: samples.len() }
}

/// A validation split's ground truth by sequence (frames without a sequence each stand alone).
pub struct Groups {
    pub frames: Vec<Vec<FrameInfo>>,
}

impl Groups {
    pub fn new(infos: Vec<FrameInfo>) -> Self {
        let mut by: BTreeMap<String, Vec<FrameInfo>> = BTreeMap::new();
        for i in infos {
            let key = i.sequence.clone().unwrap_or_else(|| i.id.clone());
            by.entry(key).or_default().push(i);
        }
        Self { frames: by.into_values().collect() }
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// The drawn groups' frames and `dets` on them, each copy of a frame under its own id.
    fn draw(&self, draw: &[usize], dets: &Detections) -> (Vec<FrameInfo>, Detections) {
        let mut gt = Vec::new();
        let mut out = Detections::default();
        for (k, &g) in draw.iter().enumerate() {
            for info in &self.frames[g] {
                let id = format!("{}#{k}", info.id);
                let d: Vec<Detection> = dets.frames.get(&info.id).cloned().unwrap_or_default();
                out.frames.insert(id.clone(), d);
                gt.push(FrameInfo { id, ..info.clone() });
            }
        }
        (gt, out)
    }

    /// The report of `dets` on the drawn groups.
    pub fn report(&self, draw: &[usize], dets: &Detections, opts: &EvalOptions) -> Result<EvalReport, EvalError> {
        let (gt, d) = self.draw(draw, dets);
        evaluate(&gt, &d, opts)
    }

    /// `metric` of `dets` on the drawn groups.
    pub fn metric(
        &self,
        draw: &[usize],
        dets: &Detections,
        opts: &EvalOptions,
        metric: &dyn Fn(&EvalReport) -> f64,
    ) -> Result<f64, EvalError> {
        Ok(metric(&self.report(draw, dets, opts)?))
    }
}

/// One class of a comparison: AP_R40 at the strict overlap, moderate, of both detection sets
/// and `det − baseline` with its interval.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassComparison {
    pub class: String,
    /// The strict BEV / 3D overlap.
    pub iou: f64,
    pub num_gt: usize,
    /// `[BEV, 3D]` AP of the detections and of the baseline on the full split.
    pub det: [f64; 2],
    pub baseline: [f64; 2],
    pub bev: Interval,
    pub d3: Interval,
}

/// [`compare`]'s result: the classes, and how many sequences the bootstrap drew from.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    /// The ground truth's sequences, the bootstrap's unit.
    pub sequences: usize,
    pub classes: Vec<ClassComparison>,
}

/// `det − baseline` per class (strict BEV and 3D AP_R40, moderate) with a paired bootstrap of
/// `resamples` draws of `gt`'s sequences (seeded: the same draws for the same split).
pub fn compare(
    gt: &[FrameInfo],
    det: &Detections,
    baseline: &Detections,
    opts: &EvalOptions,
    resamples: usize,
    seed: u64,
) -> Result<Comparison, EvalError> {
    let opts = EvalOptions { per_platform: false, per_sequence: false, ..opts.clone() };
    let groups = Groups::new(gt.to_vec());
    if groups.is_empty() {
        return Err(EvalError::Input("a comparison needs ground-truth frames".into()));
    }
    let mut per_draw: Vec<(ApSummary, ApSummary)> = Vec::new();
    for d in draws(&[groups.len()], resamples, seed) {
        let a = summarize(&groups.report(&d[0], det, &opts)?);
        let b = summarize(&groups.report(&d[0], baseline, &opts)?);
        per_draw.push((a, b));
    }
    let find = |v: &ApSummary, class: &str| v.get(class).map(|c| [c.bev_r40, c.d3_r40]);
    let (full_det, full_base) = &per_draw[0];
    let mut out = Vec::new();
    for c in &full_det.classes {
        let Some(base) = find(full_base, &c.class) else { continue };
        // Per draw: det − baseline of metric `m` (NaN where a draw lacks the class).
        let diffs = |m: usize| -> Vec<f64> {
            per_draw
                .iter()
                .map(|(a, b)| match (find(a, &c.class), find(b, &c.class)) {
                    (Some(x), Some(y)) => x[m] - y[m],
                    _ => f64::NAN,
                })
                .collect()
        };
        out.push(ClassComparison {
            class: c.class.clone(),
            iou: c.iou,
            num_gt: c.num_gt,
            det: [c.bev_r40, c.d3_r40],
            baseline: base,
            bev: interval(&diffs(0)),
            d3: interval(&diffs(1)),
        });
    }
    Ok(Comparison { sequences: groups.len(), classes: out })
}

/// The comparison as a markdown table, `det` and `baseline` naming the two sets.
pub fn format_comparison(rows: &[ClassComparison], det: &str, baseline: &str, sequences: usize) -> String {
    let resamples = rows.iter().map(|r| r.bev.resamples).max().unwrap_or(0);
    let mut s = format!(
        "{det} − {baseline}: AP_R40 (moderate, strict overlap) and a 95 % interval from {resamples} paired draws of \
         the {sequences} validation sequences\n\n| class | num_gt | BEV {det} / {baseline} | BEV difference | 3D {det} / {baseline} | 3D difference |\n| --- | ---: | --- | --- | --- | --- |\n"
    );
    for r in rows {
        s += &format!(
            "| {} @{:.2} | {} | {:.1} / {:.1} | {} | {:.1} / {:.1} | {} |\n",
            r.class,
            r.iou,
            r.num_gt,
            r.det[0],
            r.baseline[0],
            r.bev.describe(),
            r.det[1],
            r.baseline[1],
            r.d3.describe()
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::Object;
    use pi3det_geometry::Box3d;

    /// [`draws`] and [`interval`] with `diff` computing the difference on each draw.
    fn paired_bootstrap(
        groups: &[usize],
        resamples: usize,
        seed: u64,
        diff: &dyn Fn(&[Vec<usize>]) -> f64,
    ) -> Interval {
        let diffs: Vec<f64> = draws(groups, resamples, seed).iter().map(|d| diff(d)).collect();
        interval(&diffs)
    }

    /// Noise of up to ±2 whose mean over the 24 sequences is exactly 0 (pairs ±e).
    fn zero_mean_noise(rng: &mut rand::rngs::StdRng) -> Vec<f64> {
        (0..12)
            .flat_map(|_| {
                let e = rng.random_range(0.0..2.0);
                [e, -e]
            })
            .collect()
    }

    /// A synthetic table: per sequence, row B scores its row A + 5 with noise; the difference
    /// over all sequences is exactly 5.
    #[test]
    fn a_known_difference_lies_in_its_interval_and_is_resolved() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let a: Vec<f64> = (0..24).map(|_| rng.random_range(30.0..70.0)).collect();
        let b: Vec<f64> = a.iter().zip(zero_mean_noise(&mut rng)).map(|(x, e)| x + 5.0 + e).collect();
        let mean = |v: &[f64], d: &[usize]| d.iter().map(|&i| v[i]).sum::<f64>() / d.len() as f64;
        let i = paired_bootstrap(&[24], 500, 0, &|d| mean(&b, &d[0]) - mean(&a, &d[0]));
        assert!((i.diff - 5.0).abs() < 1e-9 && i.lo < 5.0 && 5.0 < i.hi && i.resolved(), "{i:?}");
        assert!(i.hi - i.lo < 2.0, "paired: the sequences' own spread cancels: {i:?}");
        // No difference: the interval holds 0 and the ordering is not resolved.
        let c: Vec<f64> = a.iter().zip(zero_mean_noise(&mut rng)).map(|(x, e)| x + e).collect();
        let j = paired_bootstrap(&[24], 500, 0, &|d| mean(&c, &d[0]) - mean(&a, &d[0]));
        assert!(j.lo < 0.0 && 0.0 < j.hi && !j.resolved(), "{j:?}");
        // Two seeds: the seed-mean difference.
        let k = paired_bootstrap(&[24, 24], 200, 0, &|d| {
            (mean(&b, &d[0]) - mean(&a, &d[0]) + mean(&c, &d[1]) - mean(&a, &d[1])) / 2.0
        });
        assert!((k.diff - 2.5).abs() < 1e-9 && k.lo < 2.5 && 2.5 < k.hi, "{k:?}");
    }

    #[test]
    fn percentiles_of_a_known_sample() {
        let mut v: Vec<f64> = (0..=100).map(f64::from).collect();
        let (lo, hi) = percentiles_95(&mut v);
        assert!((lo - 2.5).abs() < 1e-9 && (hi - 97.5).abs() < 1e-9);
        let i = interval(&[1.0, f64::NAN]);
        assert_eq!((i.diff, i.resamples), (1.0, 0));
        assert!(i.describe().contains("no interval"));
    }

    /// Ten sequences of four frames with one car each. `good` finds every car exactly; `half`
    /// finds those of the first five sequences only: a difference the bootstrap resolves. A set
    /// against itself differs by exactly 0 on every draw.
    #[test]
    fn a_detector_that_misses_half_the_sequences_is_resolved_worse() {
        let car = Box3d::new(10.0, 0.0, -1.0, 3.9, 1.6, 1.5, 0.0);
        let mut gt = Vec::new();
        let (mut good, mut half) = (Detections::default(), Detections::default());
        for s in 0..10 {
            for f in 0..4 {
                let id = format!("{s:02}{f:02}");
                let mut info = FrameInfo::new(id.clone(), Default::default());
                info.sequence = Some(format!("seq{s}"));
                info.objects.push(Object::new("Car", car));
                gt.push(info);
                let d = Detections::from_objects([(
                    id.clone(),
                    vec![Object { score: Some(0.9), ..Object::new("Car", car) }],
                )])
                .unwrap();
                good.frames.extend(d.frames.clone());
                half.frames.insert(id.clone(), if s < 5 { d.frames[&id].clone() } else { Vec::new() });
            }
        }
        let opts = EvalOptions { classes: vec!["Car".into()], ..EvalOptions::default() };
        let c = compare(&gt, &half, &good, &opts, 100, 0).unwrap();
        let rows = c.classes;
        assert_eq!((rows.len(), c.sequences), (1, 10));
        let r = &rows[0];
        assert_eq!((r.class.as_str(), r.num_gt), ("Car", 40));
        assert!(r.det[0] < r.baseline[0] && r.baseline[0] > 95.0, "{r:?}");
        assert!(r.bev.diff < -20.0 && r.bev.resolved() && r.bev.hi < 0.0, "{r:?}");
        assert_eq!(r.bev.resamples, 100);
        let same = compare(&gt, &good, &good, &opts, 50, 0).unwrap().classes;
        assert_eq!((same[0].bev.lo, same[0].bev.hi, same[0].bev.resolved()), (0.0, 0.0, false));
        let table = format_comparison(&rows, "half", "good", 10);
        assert!(table.contains("| Car @0.70 | 40 |") && table.contains("resolved"), "{table}");
    }
}
