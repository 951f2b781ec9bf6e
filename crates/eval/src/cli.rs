//! `pi3det eval`: arguments (clap) and runner, for the `pi3det` binary to mount as a subcommand.

use std::path::PathBuf;
use std::time::Instant;

use crate::classes::Overlaps;
use crate::detections::Detections;
use crate::error::EvalError;
use crate::options::EvalOptions;
use crate::report::format_report;
use crate::run::{evaluate_dataset, EvalReport};

/// Evaluate detections with the KITTI protocol (OpenPCDet / mmdet3d numbers: bbox, BEV, 3D and
/// AOS average precision, R11 and R40, easy / moderate / hard).
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub struct EvalArgs {
    /// Ground truth: a Pi3DET folder or info .pkl, a KITTI folder (with velodyne/, label_2/,
    /// calib/), or an mmdet3d nuScenes info .pkl.
    #[arg(long, value_name = "DATASET")]
    pub gt: PathBuf,
    /// Detections: an OpenPCDet result.pkl, a KITTI result folder (<frame_id>.txt with a score
    /// column), or pi3det JSON lines (.jsonl).
    #[arg(long, value_name = "DETECTIONS")]
    pub det: PathBuf,
    /// Classes to evaluate, comma-separated KITTI names [default: Car, Pedestrian, Cyclist as
    /// far as they occur in the ground truth].
    #[arg(long, value_delimiter = ',')]
    pub classes: Vec<String>,
    /// Drop detections scoring below this.
    #[arg(long, value_name = "SCORE")]
    pub score_threshold: Option<f64>,
    /// The paper's setting: score threshold 0.2 (unless --score-threshold is given).
    #[arg(long)]
    pub paper: bool,
    /// Keep only boxes whose BEV centre (LiDAR frame) is inside this range.
    #[arg(long, num_args = 4, value_names = ["X_MIN", "Y_MIN", "X_MAX", "Y_MAX"], allow_negative_numbers = true)]
    pub bev_range: Option<Vec<f64>>,
    /// Map a dataset class name to a KITTI name (repeatable), e.g. --map truck=Car.
    #[arg(long = "map", value_name = "NAME=KITTI_NAME")]
    pub map: Vec<String>,
    /// Do not apply the default mapping (Vehicle=Car).
    #[arg(long)]
    pub no_default_map: bool,
    /// IoU thresholds of a class (repeatable): CLASS=BBOX,BEV,3D/BBOX,BEV,3D (strict/loose).
    #[arg(long = "overlaps", value_name = "CLASS=S,S,S/L,L,L")]
    pub overlaps: Vec<String>,
    /// Do not add per-platform and per-sequence results.
    #[arg(long)]
    pub no_breakdown: bool,
    /// Image size used to clip projected 2D boxes of LiDAR detections on KITTI frames when the
    /// detections carry none.
    #[arg(long, num_args = 2, value_names = ["WIDTH", "HEIGHT"])]
    pub image_size: Option<Vec<f64>>,
    /// Skip detection frames that are not in the ground truth instead of failing.
    #[arg(long)]
    pub allow_unknown_frames: bool,
    /// Print the report as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report to this file.
    #[arg(long, value_name = "FILE")]
    pub output: Option<PathBuf>,
}

fn parse_overlap(spec: &str) -> Result<(String, Overlaps), EvalError> {
    let bad = || EvalError::Option(format!("--overlaps {spec:?}: expected CLASS=BBOX,BEV,3D/BBOX,BEV,3D"));
    let (class, sets) = spec.split_once('=').ok_or_else(bad)?;
    let (strict, loose) = sets.split_once('/').ok_or_else(bad)?;
    let three = |s: &str| -> Result<[f64; 3], EvalError> {
        let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|_| bad())?;
        v.try_into().map_err(|_| bad())
    };
    Ok((class.trim().to_string(), Overlaps { strict: three(strict)?, loose: three(loose)? }))
}

impl EvalArgs {
    /// The options these arguments ask for.
    pub fn options(&self) -> Result<EvalOptions, EvalError> {
        let mut o = EvalOptions { classes: self.classes.clone(), ..EvalOptions::default() };
        o.score_threshold = self.score_threshold.or(self.paper.then_some(0.2));
        if let Some(r) = &self.bev_range {
            o.bev_range =
                Some(r.as_slice().try_into().map_err(|_| EvalError::Option("--bev-range takes 4 numbers".into()))?);
        }
        if self.no_default_map {
            o.name_map.clear();
        }
        for m in &self.map {
            let (k, v) = m
                .split_once('=')
                .filter(|(k, v)| !k.trim().is_empty() && !v.trim().is_empty())
                .ok_or_else(|| EvalError::Option(format!("--map {m:?}: expected NAME=KITTI_NAME")))?;
            o.name_map.insert(k.trim().to_string(), v.trim().to_string());
        }
        for s in &self.overlaps {
            let (class, ov) = parse_overlap(s)?;
            o.overlaps.insert(class, ov);
        }
        if self.no_breakdown {
            o.per_platform = false;
            o.per_sequence = false;
        }
        if let Some(s) = &self.image_size {
            o.image_size =
                s.as_slice().try_into().map_err(|_| EvalError::Option("--image-size takes 2 numbers".into()))?;
        }
        o.allow_unknown_frames = self.allow_unknown_frames;
        o.validate()?;
        Ok(o)
    }

    /// Reads both inputs and evaluates.
    pub fn evaluate(&self) -> Result<EvalReport, EvalError> {
        let opts = self.options()?;
        let t = Instant::now();
        let ds = pi3det_data::open(&self.gt)?;
        let dets = Detections::read(&self.det)?;
        tracing::info!(
            "read {} ground-truth frames and {} detections in {} frames ({:.3} s)",
            ds.len(),
            dets.num_detections(),
            dets.frames.len(),
            t.elapsed().as_secs_f64()
        );
        let t = Instant::now();
        let report = evaluate_dataset(ds.as_ref(), &dets, &opts)?;
        tracing::info!("evaluated in {:.3} s", t.elapsed().as_secs_f64());
        Ok(report)
    }
}

/// Runs `pi3det eval`: prints the text report (or JSON with `--json`) to stdout.
pub fn run(args: &EvalArgs) -> Result<(), EvalError> {
    let report = args.evaluate()?;
    let json = || serde_json::to_string_pretty(&report).map_err(|e| EvalError::Input(format!("JSON output: {e}")));
    if let Some(path) = &args.output {
        std::fs::write(path, json()? + "\n").map_err(|e| EvalError::io(path, e))?;
    }
    if args.json {
        println!("{}", json()?);
    } else {
        print!("{}", format_report(&report));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        eval: EvalArgs,
    }

    #[test]
    fn parses_options() {
        let c = Cli::try_parse_from([
            "x",
            "--gt",
            "g",
            "--det",
            "d",
            "--classes",
            "Car,Pedestrian",
            "--paper",
            "--bev-range",
            "0",
            "-40",
            "70.4",
            "40",
            "--map",
            "truck=Car",
            "--overlaps",
            "Sign=0.7,0.7,0.7/0.5,0.5,0.5",
        ])
        .unwrap();
        let o = c.eval.options().unwrap();
        assert_eq!(o.score_threshold, Some(0.2));
        assert_eq!(o.bev_range, Some([0.0, -40.0, 70.4, 40.0]));
        assert_eq!(o.name_map.get("truck").map(String::as_str), Some("Car"));
        assert_eq!(o.overlaps["Sign"].loose, [0.5; 3]);
        assert_eq!(o.classes, ["Car", "Pedestrian"]);
        let c = Cli::try_parse_from(["x", "--gt", "g", "--det", "d", "--overlaps", "Sign=0.7"]).unwrap();
        assert!(c.eval.options().is_err());
    }
}
