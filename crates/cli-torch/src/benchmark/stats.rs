//! How sure a suite's table is: each row's difference to source-only with a 95 % interval from
//! a paired bootstrap over validation sequences (the sequence, not the frame, is the unit: the
//! frames of one sequence share their scene), averaged over the suite's seeds.
//!
//! A draw picks, per seed, as many sequences as the validation split has, with replacement
//! ([`pi3det_eval::bootstrap`]); the row and source-only are evaluated on the same draw, and the
//! interval is the 2.5 / 97.5 % percentile of the seed-mean differences.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pi3det_eval::Detections;

use super::suite::{Cell, MethodKind, MethodSpec, Suite};
use super::table::{CellResult, Status};
use pi3det_adapt::pipeline::Component;

pub use pi3det_eval::bootstrap::{draws, interval, Groups, Interval};

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
            // Each method's seed-mean metric per draw, computed once (source-only and the rows that
            // components are measured against are needed more than once).
            let mut memo: Vec<Option<Option<OnDraws>>> = vec![None; suite.methods.len()];
            let mut on_draws_once = |mi: usize| -> Option<OnDraws> {
                memo[mi].get_or_insert_with(|| on_draws(mi).map(|r| r.map_err(|e| format!("{e:#}")))).clone()
            };
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
                    Some(si) if si != mi && resamples > 0 => difference_cells(on_draws_once(mi), on_draws_once(si)),
                    _ => " – | – | |".to_string(),
                };
                row += &compared;
                s += &row;
                s += "\n";
            }
            // Paper Table 5's reading: what one component adds to the row without it.
            let steps = component_steps(&suite.methods);
            if resamples > 0 && !steps.is_empty() {
                s +=
                    "\nWhat each component adds: the row with it − the row without it, seed mean and 95 % interval\n\n\
                      | Component | row − row without it | 95 % interval | |\n| --- | ---: | --- | --- |\n";
                for step in steps {
                    let cells = difference_cells(on_draws_once(step.with), on_draws_once(step.without));
                    s += &format!(
                        "| +{} ({} − {}) |{cells}\n",
                        step.added,
                        suite.methods[step.with].label(),
                        suite.methods[step.without].label()
                    );
                }
            }
        }
    }
    Ok(s)
}

/// A row's seed-mean metric per bootstrap draw, or why it could not be computed.
type OnDraws = std::result::Result<Vec<f64>, String>;

/// `| difference | [lo, hi] | mark |` of `row − reference` per draw (without the leading `|`).
fn difference_cells(row: Option<OnDraws>, reference: Option<OnDraws>) -> String {
    match (reference, row) {
        (Some(Ok(r)), Some(Ok(v))) => {
            let diffs: Vec<f64> = v.iter().zip(&r).map(|(a, b)| a - b).collect();
            let i = interval(&diffs);
            let mark = if i.resolved() { "✓" } else { "~" };
            format!(" {:+.1} | [{:+.1}, {:+.1}] | {mark} |", i.diff, i.lo, i.hi)
        }
        (Some(Err(e)), _) | (_, Some(Err(e))) => format!(" – | no interval: {e} | |"),
        _ => " – | – | |".to_string(),
    }
}

/// One component's step in an ablation: the Pi3DET-Net row `with` it and the row `without` it
/// (the same components but that one).
#[derive(Debug, PartialEq)]
pub struct ComponentStep {
    pub added: String,
    pub with: usize,
    pub without: usize,
}

/// The suite's component steps: for each Pi3DET-Net row with listed components, the row without
/// exactly one of them — the nearest such row above it, so a cumulative ablation reads down.
pub fn component_steps(methods: &[MethodSpec]) -> Vec<ComponentStep> {
    let set = |m: &MethodSpec| -> Option<std::collections::BTreeSet<Component>> {
        (m.kind == MethodKind::Pi3detNet).then(|| m.components.as_ref().map(|c| c.iter().copied().collect()))?
    };
    let mut out = Vec::new();
    for (with, m) in methods.iter().enumerate() {
        let Some(c) = set(m) else { continue };
        let candidates = (0..with).rev().chain(with + 1..methods.len());
        let found = candidates.filter_map(|j| Some((j, set(&methods[j])?))).find_map(|(j, d)| {
            let added: Vec<&Component> = c.difference(&d).collect();
            (d.is_subset(&c) && added.len() == 1).then(|| (j, *added[0]))
        });
        if let Some((without, added)) = found {
            out.push(ComponentStep { added: added.to_string(), with, without });
        }
    }
    out
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

    #[test]
    fn spread_is_half_the_range() {
        assert_eq!(mean_spread(&[70.0, 72.0]), (71.0, 1.0));
    }
}
