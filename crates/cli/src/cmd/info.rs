//! `pi3det info PATH`: format detection and dataset statistics.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use pi3det_data::summary::{summarize, Counts, Summary};

#[derive(clap::Args)]
pub struct InfoArgs {
    /// A Pi3DET root (pi3det_infos_*.pkl), a KITTI split folder, an mmdet3d info .pkl, or
    /// sequences of the full Pi3DET release (a folder with *data*.h5, or `processed/` above them).
    pub path: PathBuf,
    /// Sequences: read the frames every file has when a pose file or ts_start is shorter.
    #[arg(long)]
    pub truncate: bool,
    /// Print JSON instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Also list every box with its class and the number of points inside it.
    #[arg(long)]
    pub per_box: bool,
}

pub fn run(args: &InfoArgs) -> anyhow::Result<()> {
    // pi3det-data cannot depend on the sequence reader, so sequences are detected here first.
    let options = super::convert::sequence_options(args.truncate, Default::default());
    let dataset = pi3det_sequence::open(&args.path, options)?;
    let bar = ProgressBar::new(dataset.len() as u64)
        .with_style(ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames").expect("valid template"))
        .with_message("reading");
    let summary = summarize(dataset.as_ref(), args.per_box, &|| bar.inc(1))
        .with_context(|| format!("summarising {}", args.path.display()))?;
    bar.finish_and_clear();
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &summary)?;
        writeln!(out)?;
    } else {
        write!(out, "{}", render(&args.path.display().to_string(), &summary))?;
    }
    Ok(())
}

fn classes(summary: &Summary) -> Vec<String> {
    summary.total.boxes_per_class.keys().cloned().collect()
}

fn row(label: &str, c: &Counts, classes: &[String]) -> String {
    let mut s = format!("| {label} | {} | {:.3} | {} |", c.frames, c.points as f64 / 1e6, c.boxes());
    for k in classes {
        s += &format!(" {} |", c.boxes_per_class.get(k).copied().unwrap_or(0));
    }
    s + "\n"
}

/// Markdown tables: totals, per platform, per sequence, and optionally per box.
fn render(path: &str, summary: &Summary) -> String {
    let classes = classes(summary);
    let header = {
        let mut h = String::from("| group | frames | points (M) | boxes |");
        let mut sep = String::from("|---|---:|---:|---:|");
        for k in &classes {
            h += &format!(" {k} |");
            sep += "---:|";
        }
        format!("{h}\n{sep}\n")
    };
    let mut s = format!("# {path}\nformat: {}\n\n", summary.format);
    s += &header;
    s += &row("all", &summary.total, &classes);
    for (p, c) in &summary.per_platform {
        s += &row(&format!("platform {p}"), c, &classes);
    }
    if !summary.per_sequence.is_empty() {
        s += "\n";
        s += &header;
        for (q, c) in &summary.per_sequence {
            s += &row(&format!("sequence {q}"), c, &classes);
        }
    }
    if summary.total.dropped_points > 0 {
        s += &format!(
            "\nwarning: {} points with NaN or infinite coordinates were dropped\n",
            summary.total.dropped_points
        );
    }
    if !summary.per_box.is_empty() {
        s += "\n| frame | class | points inside | stored |\n|---|---|---:|---:|\n";
        for b in &summary.per_box {
            let stored = b.stored_points.map_or("-".to_string(), |n| n.to_string());
            s += &format!("| {} | {} | {} | {stored} |\n", b.frame_id, b.class, b.points);
        }
    }
    s
}
