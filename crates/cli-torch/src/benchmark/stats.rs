//! How sure a suite's table is: each row's difference to source-only with a 95 % interval from
//! a paired bootstrap over validation sequences (the sequence, not the frame, is the unit: the
//! frames of one sequence share their scene), averaged over the suite's seeds.
//!
//! A draw picks, per seed, as many sequences as the validation split has, with replacement; the
//! row and source-only are evaluated on the same draw (paired), and AP is recomputed on the
//! drawn frames, since AP does not add over sequences. The interval is the 2.5 / 97.5 %
//! percentile of the seed-mean differences; an ordering is *resolved* when it excludes 0.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pi3det_data::FrameInfo;
use pi3det_eval::{Detection, Detections, EvalOptions};
use rand::{Rng, SeedableRng};
use serde::Serialize;

use super::suite::{Cell, MethodKind, Suite};
use super::table::{CellResult, Status};

/// A difference (row − reference) and its bootstrap interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Interval {
    /// On the full validation splits.
    pub diff: f64,
    pub lo: f64,
    pub hi: f64,
    pub resamples: usize,
}

impl Interval {
    /// The interval excludes 0: the sign of the difference is resolved.
    pub fn resolved(&self) -> bool {
        self.lo > 0.0 || self.hi < 0.0
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
/// of unit `u` (a seed); each draw holds, per unit, as many group indices drawn with replacement.
/// The first draw is the identity (the full splits).
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

/// [`draws`] and [`interval`] with `diff` computing the difference on each draw (the tests'
/// shorthand; the comparison table shares one set of draws between rows).
#[cfg(test)]
pub fn paired_bootstrap(
    groups: &[usize],
    resamples: usize,
    seed: u64,
    diff: &mut dyn FnMut(&[Vec<usize>]) -> Result<f64>,
) -> Result<Interval> {
    let diffs = draws(groups, resamples, seed).iter().map(|d| diff(d)).collect::<Result<Vec<f64>>>()?;
    Ok(interval(&diffs))
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

    /// `metric` of `dets` on the drawn groups.
    pub fn metric(
        &self,
        draw: &[usize],
        dets: &Detections,
        opts: &EvalOptions,
        metric: &dyn Fn(&pi3det_eval::EvalReport) -> f64,
    ) -> Result<f64> {
        let (gt, d) = self.draw(draw, dets);
        let report = pi3det_eval::evaluate(&gt, &d, opts).context("evaluating a bootstrap draw")?;
        Ok(metric(&report))
    }
}

/// One seed's run of a suite: its output folder and its cells' results.
pub struct SeedRun<'a> {
    pub seed: u64,
    pub suite: &'a Suite,
    pub out: &'a Path,
    pub results: &'a [CellResult],
}

/// The validation split of `target` in `run`'s output folder, by sequence.
fn validation_groups(run: &SeedRun<'_>, target: &str) -> Result<Groups> {
    let ctx = super::methods::Ctx { suite: run.suite, out: run.out, device: tch::Device::Cpu };
    let mut log = super::methods::Log::create(&run.out.join("stats_log.txt"), "stats".into())?;
    let val = ctx.split(target, false, &mut log)?;
    Ok(Groups::new(val.infos()?))
}

/// Where a finished cell left its validation detections.
fn detections_path(out: &Path, id: &str) -> Option<PathBuf> {
    let dir = out.join("cells").join(super::cell_dir_name(id));
    [dir.join("val_detections.jsonl"), dir.join("adapt").join("val_adapted.jsonl")].into_iter().find(|p| p.is_file())
}

/// The markdown section: per detector and task, each method's strict Car (first class) BEV per
/// seed, their mean ± spread, `num_gt`, and the difference to source-only with its interval.
/// `resamples` = 0: values only.
pub fn comparison(runs: &[SeedRun<'_>], resamples: usize) -> Result<String> {
    let Some(first) = runs.first() else { return Ok(String::new()) };
    let suite = first.suite;
    let mut s = String::new();
    for (det_name, det) in &suite.detectors {
        let Some(class) = det.config.classes.first() else { continue };
        let r = det.config.pillars.point_cloud_range;
        let mut opts = pi3det_nn::eval::options(&det.config.classes, Some([r[0], r[1], r[3], r[4]]), None);
        opts.per_platform = false;
        let class_ref = class.clone();
        let metric = move |rep: &pi3det_eval::EvalReport| {
            pi3det_nn::eval::summarize(rep).get(&class_ref).map_or(f64::NAN, |c| c.bev_r40)
        };
        s += &format!(
            "\n## `{det_name}` — {class} BEV@strict AP_R40 over seeds {:?}: mean ± half-range over seeds, and the \
             difference to source-only with its 95 % interval ({resamples} paired draws of validation sequences; \
             ✓ = resolved, ~ = within noise)\n",
            runs.iter().map(|r| r.seed).collect::<Vec<_>>()
        );
        for task in &suite.tasks {
            // Per seed: the target's validation frames by sequence.
            let groups: Vec<Groups> = match runs.iter().map(|run| validation_groups(run, &task.target)).collect() {
                Ok(g) => g,
                Err(e) => {
                    s += &format!("\n### {}: no intervals, its validation split is unreadable ({e:#})\n", task.name);
                    continue;
                }
            };
            let sizes: Vec<usize> = groups.iter().map(Groups::len).collect();
            let cell = |run: &SeedRun<'_>, m: usize| {
                let id = run.suite.cell_id(&Cell { task: task.name.clone(), method: m, detector: det_name.clone() });
                let r = run.results.iter().find(|r| r.id == id && r.status == Status::Done)?;
                Some((r.clone(), detections_path(run.out, &id)?))
            };
            let source = suite.methods.iter().position(|m| m.kind == MethodKind::SourceOnly);
            s += &format!(
                "\n### {} ({} validation sequences{})\n\n| Method | per seed | mean ± spread | num_gt | − source-only | 95 % interval | |\n| --- | --- | --- | ---: | ---: | --- | --- |\n",
                task.name,
                sizes.first().copied().unwrap_or(0),
                if sizes.windows(2).all(|w| w[0] == w[1]) { "" } else { " (differs per seed)" }
            );
            // One set of draws per task: every row is paired with source-only on the same draws,
            // and source-only is evaluated on them once.
            let draws = draws(&sizes, resamples, 0);
            let on_draws = |mi: usize| -> Option<Result<Vec<f64>>> {
                let paths: Vec<PathBuf> =
                    runs.iter().map(|run| cell(run, mi).map(|(_, p)| p)).collect::<Option<_>>()?;
                Some((|| {
                    let dets = paths
                        .iter()
                        .map(|p| Detections::read(p).with_context(|| format!("reading {}", p.display())))
                        .collect::<Result<Vec<_>>>()?;
                    let mut means = Vec::with_capacity(draws.len());
                    for draw in &draws {
                        let mut sum = 0.0;
                        for ((g, d), det) in groups.iter().zip(draw).zip(&dets) {
                            sum += g.metric(d, det, &opts, &metric)?;
                        }
                        means.push(sum / dets.len() as f64);
                    }
                    Ok(means)
                })())
            };
            let mut reference: Option<Option<Result<Vec<f64>>>> = None;
            for (mi, m) in suite.methods.iter().enumerate() {
                let cells: Vec<Option<(CellResult, PathBuf)>> = runs.iter().map(|run| cell(run, mi)).collect();
                let values: Vec<f64> = cells
                    .iter()
                    .filter_map(|c| c.as_ref().and_then(|(r, _)| r.ap.as_ref()?.get(class).map(|c| c.bev_r40)))
                    .collect();
                if values.is_empty() {
                    s += &format!("| {} | – | – | – | – | – | |\n", m.label());
                    continue;
                }
                let num_gt = cells
                    .iter()
                    .find_map(|c| c.as_ref().and_then(|(r, _)| r.ap.as_ref()?.get(class).map(|c| c.num_gt)))
                    .unwrap_or(0);
                let (mean, spread) = mean_spread(&values);
                let per_seed: Vec<String> = values.iter().map(|v| format!("{v:.1}")).collect();
                let spread = if values.len() > 1 { format!(" ± {spread:.1}") } else { String::new() };
                let mut row = format!("| {} | {} | {mean:.1}{spread} | {num_gt} |", m.label(), per_seed.join(" / "));
                let compared = match source {
                    Some(si) if si != mi && resamples > 0 => {
                        let reference = reference.get_or_insert_with(|| on_draws(si));
                        match (reference.as_ref(), on_draws(mi).as_ref()) {
                            (Some(Ok(r)), Some(Ok(v))) => {
                                let diffs: Vec<f64> = v.iter().zip(r).map(|(a, b)| a - b).collect();
                                let i = interval(&diffs);
                                let mark = if i.resolved() { "✓" } else { "~" };
                                format!(" {:+.1} | [{:+.1}, {:+.1}] | {mark} |\n", i.diff, i.lo, i.hi)
                            }
                            (Some(Err(e)), _) | (_, Some(Err(e))) => format!(" – | no interval: {e:#} | |\n"),
                            _ => " – | – | |\n".to_string(),
                        }
                    }
                    _ => " – | – | |\n".to_string(),
                };
                row += &compared;
                s += &row;
            }
        }
    }
    Ok(s)
}

/// Mean and half the range of values (the spread over seeds).
pub fn mean_spread(values: &[f64]) -> (f64, f64) {
    if values.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    let (lo, hi) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    (mean, (hi - lo) / 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let i = paired_bootstrap(&[24], 500, 0, &mut |d| Ok(mean(&b, &d[0]) - mean(&a, &d[0]))).unwrap();
        assert!((i.diff - 5.0).abs() < 1e-9 && i.lo < 5.0 && 5.0 < i.hi && i.resolved(), "{i:?}");
        assert!(i.hi - i.lo < 2.0, "paired: the sequences' own spread cancels: {i:?}");
        // No difference: the interval holds 0 and the ordering is not resolved.
        let c: Vec<f64> = a.iter().zip(zero_mean_noise(&mut rng)).map(|(x, e)| x + e).collect();
        let j = paired_bootstrap(&[24], 500, 0, &mut |d| Ok(mean(&c, &d[0]) - mean(&a, &d[0]))).unwrap();
        assert!(j.lo < 0.0 && 0.0 < j.hi && !j.resolved(), "{j:?}");
        // Two seeds: the seed-mean difference.
        let k = paired_bootstrap(&[24, 24], 200, 0, &mut |d| {
            Ok((mean(&b, &d[0]) - mean(&a, &d[0]) + mean(&c, &d[1]) - mean(&a, &d[1])) / 2.0)
        })
        .unwrap();
        assert!((k.diff - 2.5).abs() < 1e-9 && k.lo < 2.5 && 2.5 < k.hi, "{k:?}");
    }

    #[test]
    fn percentiles_and_spread() {
        let mut v: Vec<f64> = (0..=100).map(f64::from).collect();
        let (lo, hi) = percentiles_95(&mut v);
        assert!((lo - 2.5).abs() < 1e-9 && (hi - 97.5).abs() < 1e-9);
        assert_eq!(mean_spread(&[70.0, 72.0]), (71.0, 1.0));
    }
}
