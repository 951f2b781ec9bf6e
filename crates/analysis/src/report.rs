//! Tables: markdown for people, CSV for spreadsheets (long format: one row per group and
//! statistic), JSON with every histogram, and the per-frame attitude CSV written as frames stream.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::analyze::{Analysis, FrameAttitude};
use crate::error::AnalysisError;
use crate::group::GroupStats;
use crate::histogram::{Histogram, Histogram2d, Summary};

/// One distribution of a group, summarised.
#[derive(Debug, Clone, PartialEq)]
pub struct StatRow {
    pub statistic: &'static str,
    pub unit: &'static str,
    pub summary: Summary,
}

/// The non-empty distributions of a group, in a fixed order.
pub fn group_rows(g: &GroupStats) -> Vec<StatRow> {
    let all: [(&'static str, &'static str, &Histogram); 27] = [
        ("ego.roll", "deg", &g.ego.roll_deg),
        ("ego.pitch", "deg", &g.ego.pitch_deg),
        ("ego.yaw", "deg", &g.ego.yaw_deg),
        ("ego.roll_jitter", "deg/frame", &g.ego.roll_jitter_deg),
        ("ego.pitch_jitter", "deg/frame", &g.ego.pitch_jitter_deg),
        ("ego.yaw_jitter", "deg/frame", &g.ego.yaw_jitter_deg),
        ("ground.roll", "deg", &g.ground.roll_deg),
        ("ground.pitch", "deg", &g.ground.pitch_deg),
        ("ground.height", "m", &g.ground.height_m),
        ("ground.inlier_ratio", "", &g.ground.inlier_ratio),
        ("ground.confidence", "", &g.ground.confidence),
        ("ground.roll_error", "deg", &g.ground.roll_error_deg),
        ("ground.pitch_error", "deg", &g.ground.pitch_error_deg),
        ("ground.abs_roll_error", "deg", &g.ground.abs_roll_error_deg),
        ("ground.abs_pitch_error", "deg", &g.ground.abs_pitch_error_deg),
        ("ground.smoothed_abs_roll_error", "deg", &g.ground.smoothed_abs_roll_error_deg),
        ("ground.smoothed_abs_pitch_error", "deg", &g.ground.smoothed_abs_pitch_error_deg),
        ("elevation.z_level", "m", &g.elevation.z_level_m),
        ("targets.relative_pitch", "deg", &g.targets.relative_pitch_deg),
        ("targets.distance", "m", &g.targets.distance_m),
        ("targets_level.relative_pitch", "deg", &g.targets_level.relative_pitch_deg),
        ("boxes.objects_per_frame", "", &g.boxes.objects_per_frame),
        ("boxes.points_per_box", "", &g.boxes.points_per_box),
        ("points.x", "m", &g.points.x_m),
        ("points.y", "m", &g.points.y_m),
        ("points.z", "m", &g.points.z_m),
        ("points.intensity", "", &g.points.intensity),
    ];
    let mut rows: Vec<StatRow> = all
        .into_iter()
        .filter(|(_, _, h)| h.count() > 0)
        .map(|(statistic, unit, h)| StatRow { statistic, unit, summary: h.summary() })
        .collect();
    if g.points.points_per_frame.count() > 0 {
        rows.push(StatRow { statistic: "points.per_frame", unit: "", summary: g.points.points_per_frame.summary() });
    }
    rows
}

/// `-` for NaN, else fixed decimals.
fn num(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "-".into()
    }
}

const SUMMARY_HEADER: &str = "count,mean,std,min,p05,p25,p50,p75,p95,max";

fn summary_csv(s: &Summary) -> String {
    let f = |v: f64| if v.is_finite() { format!("{v:.6}") } else { String::new() };
    format!(
        "{},{},{},{},{},{},{},{},{},{}",
        s.count,
        f(s.mean),
        f(s.std),
        f(s.min),
        f(s.p05),
        f(s.p25),
        f(s.p50),
        f(s.p75),
        f(s.p95),
        f(s.max)
    )
}

/// CSV field quoting for free text (sequence and class names).
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// `platforms.csv`: one row per platform (and `all`) and statistic.
pub fn platforms_csv(a: &Analysis) -> String {
    let mut s = format!("platform,statistic,unit,{SUMMARY_HEADER}\n");
    let groups = a.platforms.iter().map(|(p, g)| (p.to_string(), g)).chain([("all".to_string(), &a.total)]);
    for (name, g) in groups {
        for r in group_rows(g) {
            let _ = writeln!(s, "{name},{},{},{}", r.statistic, r.unit, summary_csv(&r.summary));
        }
    }
    s
}

/// `sequences.csv`: one row per sequence and statistic.
pub fn sequences_csv(a: &Analysis) -> String {
    let mut s = format!("platform,sequence,input,statistic,unit,{SUMMARY_HEADER}\n");
    for q in a.sequences.values() {
        for r in group_rows(&q.stats) {
            let _ = writeln!(
                s,
                "{},{},{},{},{},{}",
                q.platform,
                field(&q.sequence),
                q.input,
                r.statistic,
                r.unit,
                summary_csv(&r.summary)
            );
        }
    }
    s
}

/// `classes.csv`: box length / width / height / points per class and platform.
pub fn classes_csv(a: &Analysis) -> String {
    let mut s = format!("platform,class,statistic,unit,{SUMMARY_HEADER}\n");
    let groups = a.platforms.iter().map(|(p, g)| (p.to_string(), g)).chain([("all".to_string(), &a.total)]);
    for (name, g) in groups {
        for (class, c) in &g.boxes.classes {
            for (stat, unit, h) in [
                ("length", "m", &c.length_m),
                ("width", "m", &c.width_m),
                ("height", "m", &c.height_m),
                ("points_per_box", "", &c.points_per_box),
            ] {
                let _ = writeln!(s, "{name},{},{stat},{unit},{}", field(class), summary_csv(&h.summary()));
            }
        }
    }
    s
}

fn distance_rows(s: &mut String, platform: &str, frame: &str, h: &Histogram2d) {
    for (ix, m) in h.columns.iter().enumerate() {
        if m.count == 0 {
            continue;
        }
        let (lo, hi) = h.x_edges(ix);
        let _ = writeln!(s, "{platform},{frame},{lo},{hi},{},{:.4},{:.4}", m.count, m.mean, m.std());
    }
}

/// `targets_by_distance.csv`: relative pitch mean and standard deviation per BEV-distance bin.
pub fn targets_csv(a: &Analysis) -> String {
    let mut s = String::from(
        "platform,frame,distance_lo_m,distance_hi_m,count,relative_pitch_mean_deg,relative_pitch_std_deg\n",
    );
    for (p, g) in &a.platforms {
        distance_rows(&mut s, p.as_str(), "sensor", &g.targets.pitch_by_distance);
        distance_rows(&mut s, p.as_str(), "level", &g.targets_level.pitch_by_distance);
    }
    s
}

/// Headline numbers of a platform for the summary table.
struct Headline {
    attitude_source: &'static str,
    roll: (f64, f64),
    pitch: (f64, f64),
}

/// Roll and pitch from the poses when at least as many frames have a pose as have a ground fit.
pub fn attitude_from_pose(g: &GroupStats) -> bool {
    g.ego.roll_deg.count() > 0 && g.ego.roll_deg.count() >= g.ground.roll_deg.count()
}

fn headline(g: &GroupStats) -> Headline {
    if attitude_from_pose(g) {
        let (r, p) = (&g.ego.roll_deg.moments, &g.ego.pitch_deg.moments);
        Headline { attitude_source: "pose", roll: (r.mean, r.std()), pitch: (p.mean, p.std()) }
    } else if g.ground.roll_deg.count() > 0 {
        let (r, p) = (&g.ground.roll_deg.moments, &g.ground.pitch_deg.moments);
        Headline { attitude_source: "ground fit", roll: (r.mean, r.std()), pitch: (p.mean, p.std()) }
    } else {
        Headline { attitude_source: "-", roll: (f64::NAN, f64::NAN), pitch: (f64::NAN, f64::NAN) }
    }
}

fn q(h: &Histogram, p: f64) -> f64 {
    h.quantile(p).unwrap_or(f64::NAN)
}

/// The markdown report.
pub fn markdown(a: &Analysis, figures: &[String]) -> String {
    let mut s = String::from("# Platform discrepancy statistics\n\n");
    s += "| input | format | frames used / total |\n|---|---|---:|\n";
    for i in &a.inputs {
        let _ = writeln!(s, "| {} | {:?} | {} / {} |", i.name, i.format, i.frames_used, i.frames_total);
    }
    s += "\n## Discrepancies per platform (paper Fig. 2)\n\n";
    s += "Angles in degrees, lengths in metres. Elevation: point z in a level frame centred on the sensor \
          (levelled by pose, else by the ground fit). θʳ: relative pitch from the sensor to box centres \
          (sensor frame, as the paper; > 0 above the sensor). Variances are population variances.\n\n";
    s += "| platform | frames | attitude from | roll mean | roll std | pitch mean | pitch std | roll jitter std | pitch jitter std | elevation mean | elevation var | elevation median | points above sensor | θʳ mean | θʳ var | θʳ median | θʳ median (levelled) | boxes |\n";
    s += "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for (p, g) in &a.platforms {
        let h = headline(g);
        let e = &g.elevation.z_level_m;
        let t = &g.targets.relative_pitch_deg;
        let _ = writeln!(
            s,
            "| {p} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {}% | {} | {} | {} | {} | {} |",
            g.frames,
            h.attitude_source,
            num(h.roll.0, 2),
            num(h.roll.1, 2),
            num(h.pitch.0, 2),
            num(h.pitch.1, 2),
            num(g.ego.roll_jitter_deg.moments.std(), 2),
            num(g.ego.pitch_jitter_deg.moments.std(), 2),
            num(e.moments.mean_or_nan(), 2),
            num(e.moments.variance(), 2),
            num(q(e, 0.5), 2),
            num(100.0 * g.elevation.share_above_sensor(), 1),
            num(t.moments.mean_or_nan(), 2),
            num(t.moments.variance(), 2),
            num(q(t, 0.5), 2),
            num(q(&g.targets_level.relative_pitch_deg, 0.5), 2),
            t.count()
        );
    }
    s += "\n## Pose-free attitude from the ground plane\n\n";
    s += "RANSAC + least squares per frame (ground below the sensor, within 35° of level). Errors are \
          absolute differences to the pose's roll and pitch where the data has one, per frame and after \
          temporal smoothing along the sequence; median and 95th percentile.\n\n";
    s += "| platform | frames | ground found | height median | height p05–p95 | roll std | pitch std | inlier ratio median | roll error median | roll error p95 | pitch error median | pitch error p95 | smoothed roll error median / p95 | smoothed pitch error median / p95 |\n";
    s += "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for (p, g) in &a.platforms {
        let gr = &g.ground;
        let _ = writeln!(
            s,
            "| {p} | {} | {} | {} | {}–{} | {} | {} | {} | {} | {} | {} | {} | {} / {} | {} / {} |",
            gr.attempted,
            gr.found,
            num(q(&gr.height_m, 0.5), 3),
            num(q(&gr.height_m, 0.05), 2),
            num(q(&gr.height_m, 0.95), 2),
            num(gr.roll_deg.moments.std(), 2),
            num(gr.pitch_deg.moments.std(), 2),
            num(q(&gr.inlier_ratio, 0.5), 2),
            num(q(&gr.abs_roll_error_deg, 0.5), 2),
            num(q(&gr.abs_roll_error_deg, 0.95), 2),
            num(q(&gr.abs_pitch_error_deg, 0.5), 2),
            num(q(&gr.abs_pitch_error_deg, 0.95), 2),
            num(q(&gr.smoothed_abs_roll_error_deg, 0.5), 2),
            num(q(&gr.smoothed_abs_roll_error_deg, 0.95), 2),
            num(q(&gr.smoothed_abs_pitch_error_deg, 0.5), 2),
            num(q(&gr.smoothed_abs_pitch_error_deg, 0.95), 2),
        );
    }
    s += "\n## Boxes per class (appendix Tables 12–14)\n\n";
    s += "| platform | class | boxes | per frame | length mean ± std | width mean ± std | height mean ± std | points per box median | p05–p95 |\n";
    s += "|---|---|---:|---:|---:|---:|---:|---:|---:|\n";
    for (p, g) in &a.platforms {
        for (class, c) in &g.boxes.classes {
            let ms = |h: &Histogram| format!("{} ± {}", num(h.moments.mean_or_nan(), 2), num(h.moments.std(), 2));
            let _ = writeln!(
                s,
                "| {p} | {class} | {} | {} | {} | {} | {} | {} | {}–{} |",
                c.count(),
                num(g.boxes.class_per_frame(class), 2),
                ms(&c.length_m),
                ms(&c.width_m),
                ms(&c.height_m),
                num(q(&c.points_per_box, 0.5), 0),
                num(q(&c.points_per_box, 0.05), 0),
                num(q(&c.points_per_box, 0.95), 0),
            );
        }
    }
    s += "\n## Point distributions (appendix Tables 9–11)\n\n";
    s += "| platform | points per frame | x mean ± std | y mean ± std | z mean ± std | intensity mean ± std |\n|---|---:|---:|---:|---:|---:|\n";
    for (p, g) in &a.platforms {
        let ms = |h: &Histogram| format!("{} ± {}", num(h.moments.mean_or_nan(), 2), num(h.moments.std(), 2));
        let pt = &g.points;
        let _ = writeln!(
            s,
            "| {p} | {} | {} | {} | {} | {} |",
            num(pt.points_per_frame.moments.mean_or_nan(), 0),
            ms(&pt.x_m),
            ms(&pt.y_m),
            ms(&pt.z_m),
            ms(&pt.intensity)
        );
    }
    if !a.sequences.is_empty() {
        s += "\n## Per sequence\n\n";
        s += "| sequence | frames | roll std | pitch std | elevation median | θʳ median | ground height median | objects per frame | points per box median |\n";
        s += "|---|---:|---:|---:|---:|---:|---:|---:|---:|\n";
        for (key, q_) in &a.sequences {
            let g = &q_.stats;
            let h = headline(g);
            let _ = writeln!(
                s,
                "| {key} | {} | {} | {} | {} | {} | {} | {} | {} |",
                g.frames,
                num(h.roll.1, 2),
                num(h.pitch.1, 2),
                num(q(&g.elevation.z_level_m, 0.5), 2),
                num(q(&g.targets.relative_pitch_deg, 0.5), 2),
                num(q(&g.ground.height_m, 0.5), 2),
                num(g.boxes.objects_per_frame.moments.mean_or_nan(), 2),
                num(q(&g.boxes.points_per_box, 0.5), 0),
            );
        }
    }
    if !figures.is_empty() {
        s += "\n## Figures\n\n";
        for f in figures {
            let _ = writeln!(s, "![{f}]({f})");
        }
    }
    s += "\nFull distributions: `platforms.csv`, `sequences.csv`, `classes.csv`, `targets_by_distance.csv`, \
          `attitude.csv` (per frame), `stats.json` (all histograms).\n";
    s
}

fn write(path: &Path, text: &str) -> Result<(), AnalysisError> {
    std::fs::write(path, text).map_err(|e| AnalysisError::io(path, e))
}

/// Writes the tables and `stats.json` into `dir`; returns the files written.
pub fn write_tables(a: &Analysis, dir: &Path, figures: &[String]) -> Result<Vec<PathBuf>, AnalysisError> {
    std::fs::create_dir_all(dir).map_err(|e| AnalysisError::io(dir, e))?;
    let files = [
        ("report.md", markdown(a, figures)),
        ("platforms.csv", platforms_csv(a)),
        ("sequences.csv", sequences_csv(a)),
        ("classes.csv", classes_csv(a)),
        ("targets_by_distance.csv", targets_csv(a)),
        ("stats.json", json(a)?),
    ];
    files
        .into_iter()
        .map(|(name, text)| {
            let p = dir.join(name);
            write(&p, &text).map(|_| p)
        })
        .collect()
}

/// Everything, histograms included, as pretty JSON (non-finite numbers become null).
pub fn json(a: &Analysis) -> Result<String, AnalysisError> {
    serde_json::to_string_pretty(a).map_err(|source| AnalysisError::Json { path: PathBuf::from("stats.json"), source })
}

/// The per-frame attitude table, written row by row as frames are folded.
pub struct AttitudeCsv {
    path: PathBuf,
    out: BufWriter<File>,
}

impl AttitudeCsv {
    pub const HEADER: &'static str =
        "input,frame_id,platform,sequence,timestamp_s,points,pose_roll_deg,pose_pitch_deg,pose_yaw_deg,\
ground_roll_deg,ground_pitch_deg,ground_height_m,ground_inlier_ratio,ground_confidence,ground_failure,\
smoothed_roll_deg,smoothed_pitch_deg,smoothed_height_m,smoothed_use,level_source";

    pub fn create(path: &Path) -> Result<Self, AnalysisError> {
        let file = File::create(path).map_err(|e| AnalysisError::io(path, e))?;
        let mut w = Self { path: path.to_path_buf(), out: BufWriter::new(file) };
        writeln!(w.out, "{}", Self::HEADER).map_err(|e| AnalysisError::io(path, e))?;
        Ok(w)
    }

    pub fn write(&mut self, f: &FrameAttitude) -> Result<(), AnalysisError> {
        let o = |v: Option<f64>, d: usize| v.filter(|x| x.is_finite()).map_or(String::new(), |x| format!("{x:.d$}"));
        let deg = |v: Option<f64>| o(v.map(f64::to_degrees), 4);
        let row = format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            f.input,
            field(&f.frame_id),
            f.platform,
            field(f.sequence.as_deref().unwrap_or("")),
            o(f.timestamp_s, 6),
            f.points,
            deg(f.pose.map(|p| p.roll_rad)),
            deg(f.pose.map(|p| p.pitch_rad)),
            deg(f.pose.map(|p| p.yaw_rad)),
            deg(f.ground.map(|g| g.roll_rad)),
            deg(f.ground.map(|g| g.pitch_rad)),
            o(f.ground.map(|g| g.height_m), 4),
            o(f.ground.map(|g| g.inlier_ratio), 4),
            o(f.ground.map(|g| g.confidence), 4),
            field(f.ground_failure.as_deref().unwrap_or("")),
            deg(f.smoothed.map(|s| s.roll_rad)),
            deg(f.smoothed.map(|s| s.pitch_rad)),
            o(f.smoothed.map(|s| s.height_m), 4),
            f.smoothed.map_or(String::new(), |s| format!("{:?}", s.measurement).to_lowercase()),
            format!("{:?}", f.level_source).to_lowercase(),
        );
        writeln!(self.out, "{row}").map_err(|e| AnalysisError::io(&self.path, e))
    }

    pub fn finish(mut self) -> Result<PathBuf, AnalysisError> {
        self.out.flush().map_err(|e| AnalysisError::io(&self.path, e))?;
        Ok(self.path)
    }
}
