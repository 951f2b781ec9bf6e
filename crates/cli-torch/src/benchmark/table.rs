//! The benchmark's tables in the paper's layout (Tables 2–4): per detector and class, one row per
//! method and, per task, BEV / 3D AP_R40 at the class's strict and loose IoU; best in **bold**,
//! second best _underlined_ among the methods that use no target labels. Markdown, CSV, JSON, and
//! a PNG of the share of the source-only → target-only gap each method closes.

use std::path::Path;

use anyhow::{Context, Result};
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use super::suite::{MethodKind, Suite};
use pi3det_nn::eval::ApSummary;

/// What a cell left behind (`result.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellResult {
    pub id: String,
    pub task: String,
    pub method: String,
    pub kind: MethodKind,
    pub detector: String,
    pub status: Status,
    pub error: Option<String>,
    pub ap: Option<ApSummary>,
    #[serde(default)]
    pub pseudo_labels: Vec<serde_json::Value>,
    pub seconds: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    Done,
    Failed,
}

/// The four numbers of a (result, class): BEV / 3D at the strict IoU, then at the loose one.
fn metrics(r: &CellResult, class: &str) -> Option<[f64; 4]> {
    let c = r.ap.as_ref()?.get(class)?;
    let l = c.loose;
    Some([c.bev_r40, c.d3_r40, l.map_or(f64::NAN, |l| l.bev_r40), l.map_or(f64::NAN, |l| l.d3_r40)])
}

fn ious(results: &[&CellResult], class: &str) -> (f64, f64) {
    results
        .iter()
        .find_map(|r| r.ap.as_ref()?.get(class).map(|c| (c.iou, c.loose.map_or(f64::NAN, |l| l.iou))))
        .unwrap_or((f64::NAN, f64::NAN))
}

/// Rank marks per column: indices of the best and second best ranked rows.
fn marks(values: &[Option<f64>], ranked: &[bool]) -> (Option<usize>, Option<usize>) {
    let mut idx: Vec<usize> =
        (0..values.len()).filter(|&i| ranked[i] && values[i].is_some_and(|v| v.is_finite())).collect();
    idx.sort_by(|&a, &b| values[b].unwrap_or(0.0).total_cmp(&values[a].unwrap_or(0.0)).then(a.cmp(&b)));
    (idx.first().copied(), idx.get(1).copied())
}

/// The result of each (task, method, detector) of the suite, `None` where the cell has not run.
pub type Grid<'a> = Vec<Vec<Vec<Option<&'a CellResult>>>>;

pub fn grid<'a>(suite: &Suite, results: &'a [CellResult]) -> Grid<'a> {
    let det: Vec<&String> = suite.detectors.keys().collect();
    suite
        .tasks
        .iter()
        .map(|t| {
            (0..suite.methods.len())
                .map(|m| {
                    det.iter()
                        .map(|d| {
                            let id = format!("{}/{}/{}", t.name, suite.methods[m].slug(), d);
                            results.iter().find(|r| r.id == id)
                        })
                        .collect()
                })
                .collect()
        })
        .collect()
}

/// The markdown tables.
pub fn markdown(suite: &Suite, results: &[CellResult]) -> String {
    let g = grid(suite, results);
    let mut s = format!("# Benchmark `{}`\n\nAP_R40 on each task's target validation split. **Best**, _second best_ among methods without target labels; † = trained with target labels (upper bounds).\n", suite.name);
    for (di, det) in suite.detectors.iter().enumerate() {
        for class in &det.1.config.classes {
            let all: Vec<&CellResult> = g.iter().flatten().filter_map(|m| m[di]).collect();
            let (strict, loose) = ious(&all, class);
            s += &format!("\n## {} — {class} (BEV / 3D @ {strict} · BEV / 3D @ {loose})\n\n| Method |", det.0);
            for t in &suite.tasks {
                s += &format!(" {} BEV@{strict} | 3D@{strict} | BEV@{loose} | 3D@{loose} |", t.name);
            }
            s += "\n| --- |";
            s += &" --- | --- | --- | --- |".repeat(suite.tasks.len());
            s += "\n";
            let ranked: Vec<bool> = suite.methods.iter().map(|m| !m.kind.uses_target_labels()).collect();
            // Per task and metric, the marks.
            let cols: Vec<Vec<(Option<usize>, Option<usize>)>> = (0..suite.tasks.len())
                .map(|ti| {
                    (0..4)
                        .map(|k| {
                            let v: Vec<Option<f64>> = (0..suite.methods.len())
                                .map(|m| {
                                    g[ti][m][di]
                                        .filter(|r| r.status == Status::Done)
                                        .and_then(|r| metrics(r, class))
                                        .map(|x| x[k])
                                })
                                .collect();
                            marks(&v, &ranked)
                        })
                        .collect()
                })
                .collect();
            for (mi, m) in suite.methods.iter().enumerate() {
                let dagger = if m.kind.uses_target_labels() { " †" } else { "" };
                s += &format!("| {}{dagger} |", m.label());
                for ti in 0..suite.tasks.len() {
                    match g[ti][mi][di] {
                        None => s += " – | – | – | – |",
                        Some(r) if r.status == Status::Failed => s += " failed | | | |",
                        Some(r) => {
                            let v = metrics(r, class);
                            for k in 0..4 {
                                let x = v.map_or(f64::NAN, |v| v[k]);
                                let (b, second) = cols[ti][k];
                                let cell = if x.is_finite() { format!("{x:.1}") } else { "–".into() };
                                s += &if b == Some(mi) {
                                    format!(" **{cell}** |")
                                } else if second == Some(mi) {
                                    format!(" _{cell}_ |")
                                } else {
                                    format!(" {cell} |")
                                };
                            }
                        }
                    }
                }
                s += "\n";
            }
        }
    }
    s += &notes(suite);
    let failed: Vec<&CellResult> = results.iter().filter(|r| r.status == Status::Failed).collect();
    if !failed.is_empty() {
        s += "\n## Failed cells\n\n";
        for r in failed {
            s += &format!(
                "- `{}`: {} (log: `cells/{}/log.txt`)\n",
                r.id,
                r.error.as_deref().unwrap_or("?"),
                super::cell_dir_name(&r.id)
            );
        }
    }
    let total: f64 = results.iter().map(|r| r.seconds).sum();
    s += &format!("\n{} cells, {:.0} s of cell time.\n", results.len(), total);
    s
}

/// What every row shares and where rows differ by more than their method.
pub(crate) fn notes(suite: &Suite) -> String {
    let mut s = String::from("\n## Notes\n\n");
    for (name, d) in &suite.detectors {
        if d.mixed_post {
            s += &format!(
                "- **`{name}`: the baselines post-process otherwise than Pi3DET-Net** (`mixed_post`): \
                 their differences are not the methods' alone.\n"
            );
        } else {
            s += &format!(
                "- `{name}`: every row runs `{}` with one post-processing; Pi3DET-Net adds RPJ, VPP, GTD and PFA.\n",
                d.config.name
            );
        }
    }
    let sch = &suite.schedule;
    s += &format!(
        "- Target-only trains on the target's frames, each levelled from its ground to the detector's sensor \
         height{}.\n",
        if sch.equal_steps { ", for as many steps as the source model (epochs scaled to its split)" } else { "" }
    );
    if sch.match_sensor_height {
        s += "- Rows without VPP see each target shifted by the difference of the median sensor heights \
              (one shift per dataset, ST3D's `SHIFT_COOR`).\n";
    }
    s
}

/// One CSV line per (cell, class).
pub fn csv(results: &[CellResult]) -> String {
    let mut s = String::from(
        "task,method,detector,status,class,iou,bev_r40,d3_r40,loose_iou,loose_bev_r40,loose_d3_r40,seconds\n",
    );
    for r in results {
        let q = |x: &str| if x.contains(',') { format!("\"{x}\"") } else { x.to_string() };
        match &r.ap {
            Some(ap) if r.status == Status::Done => {
                for c in &ap.classes {
                    let (li, lb, ld) = c.loose.map_or((f64::NAN, f64::NAN, f64::NAN), |l| (l.iou, l.bev_r40, l.d3_r40));
                    s += &format!(
                        "{},{},{},done,{},{},{:.4},{:.4},{},{:.4},{:.4},{:.1}\n",
                        r.task,
                        q(&r.method),
                        r.detector,
                        c.class,
                        c.iou,
                        c.bev_r40,
                        c.d3_r40,
                        li,
                        lb,
                        ld,
                        r.seconds
                    );
                }
            }
            _ => s += &format!("{},{},{},failed,,,,,,,,{:.1}\n", r.task, q(&r.method), r.detector, r.seconds),
        }
    }
    s
}

/// Share of the source-only → target-only gap closed, in percent, on the first class's strict BEV.
pub fn gap_closed(suite: &Suite, results: &[CellResult]) -> Vec<(String, Vec<(String, f64)>)> {
    let g = grid(suite, results);
    let Some((_, det)) = suite.detectors.iter().next() else { return Vec::new() };
    let Some(class) = det.config.classes.first() else { return Vec::new() };
    let find = |ti: usize, kind: MethodKind| {
        suite
            .methods
            .iter()
            .position(|m| m.kind == kind)
            .and_then(|m| g[ti][m][0])
            .and_then(|r| metrics(r, class))
            .map(|v| v[0])
    };
    let mut out = Vec::new();
    for (ti, t) in suite.tasks.iter().enumerate() {
        let (Some(src), Some(tgt)) = (find(ti, MethodKind::SourceOnly), find(ti, MethodKind::TargetOnly)) else {
            continue;
        };
        if tgt - src <= 1e-9 {
            continue;
        }
        let rows = suite
            .methods
            .iter()
            .enumerate()
            .filter(|(_, m)| !matches!(m.kind, MethodKind::SourceOnly | MethodKind::TargetOnly))
            .filter_map(|(mi, m)| {
                let v = g[ti][mi][0].filter(|r| r.status == Status::Done).and_then(|r| metrics(r, class))?[0];
                Some((m.label(), 100.0 * (v - src) / (tgt - src)))
            })
            .collect();
        out.push((t.name.clone(), rows));
    }
    out
}

/// The gap chart: per task a group of bars, one per method.
pub fn chart(suite: &Suite, results: &[CellResult], path: &Path) -> Result<()> {
    pi3det_analysis::plots::register_embedded_font().map_err(|e| anyhow::anyhow!("{e}"))?;
    let data = gap_closed(suite, results);
    let methods: Vec<String> = {
        let mut m: Vec<String> = Vec::new();
        for (_, rows) in &data {
            for (l, _) in rows {
                if !m.contains(l) {
                    m.push(l.clone());
                }
            }
        }
        m
    };
    let (lo, hi) =
        data.iter().flat_map(|(_, r)| r.iter().map(|x| x.1)).fold((0.0f64, 100.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let root = BitMapBackend::new(path, (960, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let class = suite.detectors.values().next().and_then(|d| d.config.classes.first()).cloned().unwrap_or_default();
    let n_tasks = data.len().max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{} BEV AP_R40: share of the source-only → target-only gap closed", class), ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..n_tasks as f64, (lo - 5.0)..(hi + 5.0))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let names: Vec<String> = data.iter().map(|(t, _)| t.clone()).collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n_tasks)
        .x_label_formatter(&|x| names.get(x.floor() as usize).cloned().unwrap_or_default())
        .y_desc("gap closed (%)")
        .draw()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let palette = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
    ];
    let w = 0.8 / methods.len().max(1) as f64;
    for (mi, m) in methods.iter().enumerate() {
        let color = palette[mi % palette.len()];
        let bars: Vec<Rectangle<(f64, f64)>> = data
            .iter()
            .enumerate()
            .filter_map(|(ti, (_, rows))| {
                let v = rows.iter().find(|(l, _)| l == m)?.1;
                let x0 = ti as f64 + 0.1 + mi as f64 * w;
                Some(Rectangle::new([(x0, 0.0), (x0 + w * 0.9, v)], color.filled()))
            })
            .collect();
        chart
            .draw_series(bars)
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .label(m.clone())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 10, y + 5)], color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    root.present().with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marks_skip_unranked_and_missing() {
        let v = [Some(10.0), Some(30.0), None, Some(20.0), Some(99.0)];
        assert_eq!(marks(&v, &[true, true, true, true, false]), (Some(1), Some(3)));
        assert_eq!(marks(&[None, Some(1.0)], &[true, true]), (Some(1), None));
    }
}
