//! `pi3det eval`: arguments (clap) and runner, for the `pi3det` binary to mount as a subcommand.

use std::path::PathBuf;
use std::time::Instant;

use pi3det_data::FrameInfo;
use serde::Serialize;

use crate::bootstrap::{self, compare, format_comparison};
use crate::breakdown::{breakdown, format_breakdown, Breakdown};
use crate::classes::Overlaps;
use crate::detections::Detections;
use crate::error::EvalError;
use crate::options::EvalOptions;
use crate::report::format_report;
use crate::run::{evaluate, EvalReport};

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
    /// Also print the error breakdown after the report (AP_R40 and recall by distance and by
    /// points per box, found-but-misplaced misses, localisation errors per class at the strict
    /// thresholds); with --json / --out it is the field "breakdown".
    #[arg(long)]
    pub breakdown: bool,
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
    /// Also write the JSON report to this file (`--output` is the old spelling).
    #[arg(long, value_name = "FILE", alias = "output")]
    pub out: Option<PathBuf>,
    /// Detections to compare with (same formats as --det): per class, --det − --baseline with a
    /// 95 % interval from a paired bootstrap over the ground truth's sequences, and whether the
    /// ordering is resolved or within noise; with --json / --out it is the field "comparison".
    #[arg(long, value_name = "DETECTIONS")]
    pub baseline: Option<PathBuf>,
    /// Bootstrap draws for --baseline.
    #[arg(long, default_value_t = 200, value_name = "N")]
    pub bootstrap: usize,
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
        let (infos, dets, opts) = self.read()?;
        timed(|| evaluate(&infos, &dets, &opts))
    }

    /// Reads both inputs once, evaluates and, with `--breakdown`, computes the error breakdown.
    pub fn evaluate_with_breakdown(&self) -> Result<(EvalReport, Option<Breakdown>), EvalError> {
        let (report, extra, _) = self.evaluate_all()?;
        Ok((report, extra))
    }

    /// The report, the breakdown with `--breakdown` and the comparison with `--baseline`.
    pub fn evaluate_all(&self) -> Result<(EvalReport, Option<Breakdown>, Option<Comparison>), EvalError> {
        let (infos, dets, opts) = self.read()?;
        let report = timed(|| evaluate(&infos, &dets, &opts))?;
        let extra = if self.breakdown { Some(breakdown(&infos, &dets, &opts)?) } else { None };
        let comparison = match &self.baseline {
            Some(path) => {
                let base = Detections::read(path)?;
                let t = Instant::now();
                let c = compare(&infos, &dets, &base, &opts, self.bootstrap, 0)?;
                tracing::info!("compared with {} in {:.3} s", path.display(), t.elapsed().as_secs_f64());
                Some(Comparison { baseline: path.clone(), result: c })
            }
            None => None,
        };
        Ok((report, extra, comparison))
    }

    fn read(&self) -> Result<(Vec<FrameInfo>, Detections, EvalOptions), EvalError> {
        let opts = self.options()?;
        let t = Instant::now();
        let ds = pi3det_data::open(&self.gt)?;
        let infos: Vec<FrameInfo> = ds.infos()?;
        let dets = Detections::read(&self.det)?;
        tracing::info!(
            "read {} ground-truth frames and {} detections in {} frames ({:.3} s)",
            infos.len(),
            dets.num_detections(),
            dets.frames.len(),
            t.elapsed().as_secs_f64()
        );
        Ok((infos, dets, opts))
    }
}

fn timed(f: impl FnOnce() -> Result<EvalReport, EvalError>) -> Result<EvalReport, EvalError> {
    let t = Instant::now();
    let report = f()?;
    tracing::info!("evaluated in {:.3} s", t.elapsed().as_secs_f64());
    Ok(report)
}

/// `--baseline`'s result: the detections against the baseline's, per class.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Comparison {
    pub baseline: PathBuf,
    #[serde(flatten)]
    pub result: bootstrap::Comparison,
}

/// The `--json` document: the report's fields, plus `breakdown` with `--breakdown` and
/// `comparison` with `--baseline`.
#[derive(Serialize)]
struct JsonOutput<'a> {
    #[serde(flatten)]
    report: &'a EvalReport,
    #[serde(skip_serializing_if = "Option::is_none")]
    breakdown: Option<&'a Breakdown>,
    #[serde(skip_serializing_if = "Option::is_none")]
    comparison: Option<&'a Comparison>,
}

/// The text `pi3det eval` prints: the report, then the breakdown and the comparison when there
/// are.
pub fn format_output(report: &EvalReport, breakdown: Option<&Breakdown>, comparison: Option<&Comparison>) -> String {
    let mut out = format_report(report);
    if let Some(b) = breakdown {
        out.push('\n');
        out.push_str(&format_breakdown(b));
    }
    if let Some(c) = comparison {
        out.push('\n');
        out.push_str(&format_comparison(&c.result.classes, "det", "baseline", c.result.sequences));
    }
    out
}

/// The JSON `pi3det eval --json` prints (and `--out` writes).
pub fn json_output(
    report: &EvalReport,
    breakdown: Option<&Breakdown>,
    comparison: Option<&Comparison>,
) -> Result<String, EvalError> {
    serde_json::to_string_pretty(&JsonOutput { report, breakdown, comparison })
        .map_err(|e| EvalError::Input(format!("JSON output: {e}")))
}

/// Runs `pi3det eval`: prints the text report (or JSON with `--json`) to stdout.
pub fn run(args: &EvalArgs) -> Result<(), EvalError> {
    let (report, breakdown, comparison) = args.evaluate_all()?;
    let json = || json_output(&report, breakdown.as_ref(), comparison.as_ref());
    if let Some(path) = &args.out {
        std::fs::write(path, json()? + "\n").map_err(|e| EvalError::io(path, e))?;
    }
    if args.json {
        println!("{}", json()?);
    } else {
        print!("{}", format_output(&report, breakdown.as_ref(), comparison.as_ref()));
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
        assert!(!c.eval.breakdown);
    }

    /// A Pi3DET folder with stored point counts and JSON-lines detections, through the command's
    /// own reading, text and JSON output.
    #[test]
    fn breakdown_flag_reads_files_and_adds_the_json_field() {
        use pi3det_data::{Frame, FrameInfo, Object, Platform, PointCloud};
        use pi3det_geometry::Box3d;

        let dir = tempfile::tempdir().unwrap();
        let gt = dir.path().join("gt");
        let mut w = pi3det_data::pi3det::Pi3detWriter::create(&gt, "val", false).unwrap();
        let mut lines = String::new();
        for i in 0..3 {
            let id = format!("{i:06}");
            let mut info = FrameInfo::new(id.clone(), Default::default());
            info.platform = Platform::Vehicle;
            for (k, (x, n)) in [(10.0, 500), (30.0, 12)].into_iter().enumerate() {
                let mut o = Object::new("Vehicle", Box3d::new(x, k as f64, -1.0, 3.9, 1.6, 1.5, 0.1));
                o.num_points = Some(n);
                info.objects.push(o);
            }
            w.write_frame(&Frame { info, points: PointCloud::from_xyzi(&[]) }).unwrap();
            // Only the near car is detected, 0.5 m too high.
            lines += &format!(
                "{{\"frame_id\": \"{id}\", \"names\": [\"Vehicle\"], \"scores\": [0.9], \"boxes_lidar\": [[10, 0, -0.5, 3.9, 1.6, 1.5, 0.1]]}}\n"
            );
        }
        w.finish().unwrap();
        let det = dir.path().join("det.jsonl");
        std::fs::write(&det, lines).unwrap();
        let (g, d) = (gt.to_str().unwrap(), det.to_str().unwrap());
        let args = Cli::try_parse_from(["x", "--gt", g, "--det", d, "--breakdown"]).unwrap().eval;
        let (report, b) = args.evaluate_with_breakdown().unwrap();
        let b = b.expect("--breakdown computes it");
        let car = &b.classes[0];
        assert_eq!(car.class, "Car");
        assert_eq!((car.by_points[0].result.num_gt, car.by_points[2].result.num_gt, car.gt_without_points), (3, 3, 0));
        assert_eq!((car.by_points[0].result.recall_bev, car.by_points[2].result.recall_bev), (Some(0.0), Some(1.0)));
        assert_eq!((car.misplaced.missed_3d, car.misplaced.misplaced_3d), (6, 3));
        assert!(format_output(&report, Some(&b), None).contains("Error breakdown"));
        let j: serde_json::Value = serde_json::from_str(&json_output(&report, Some(&b), None).unwrap()).unwrap();
        assert!(j["overall"]["classes"].is_array());
        assert_eq!(j["breakdown"]["classes"][0]["by_distance"][2]["ap_bev_r40_pct"], serde_json::Value::Null);
        let z = j["breakdown"]["classes"][0]["localisation"]["errors"]["z_m"]["median_abs"].as_f64().unwrap();
        assert!((z - 0.5).abs() < 1e-9, "{z}");
        // Without the flag: no breakdown, and the JSON is the report's alone.
        let args = Cli::try_parse_from(["x", "--gt", g, "--det", d]).unwrap().eval;
        let (report, b) = args.evaluate_with_breakdown().unwrap();
        assert!(b.is_none());
        let j: serde_json::Value = serde_json::from_str(&json_output(&report, None, None).unwrap()).unwrap();
        assert!(j.get("breakdown").is_none());
        assert_eq!(serde_json::from_value::<EvalReport>(j).unwrap(), report);
        // --baseline: the detections against themselves differ by exactly 0 (not resolved), in
        // the text and in the JSON; a baseline that is not there is an error naming it.
        let args =
            Cli::try_parse_from(["x", "--gt", g, "--det", d, "--baseline", d, "--bootstrap", "20"]).unwrap().eval;
        let (report, _, c) = args.evaluate_all().unwrap();
        let c = c.expect("--baseline compares");
        let car = &c.result.classes[0];
        assert_eq!((car.class.as_str(), car.bev.diff, car.bev.resamples, car.bev.resolved()), ("Car", 0.0, 20, false));
        assert_eq!(c.result.sequences, 3, "frames without a sequence stand alone");
        assert!(format_output(&report, None, Some(&c)).contains("det − baseline"));
        let j: serde_json::Value = serde_json::from_str(&json_output(&report, None, Some(&c)).unwrap()).unwrap();
        assert_eq!(j["comparison"]["classes"][0]["class"], "Car");
        let missing = dir.path().join("missing.jsonl");
        let args =
            Cli::try_parse_from(["x", "--gt", g, "--det", d, "--baseline", missing.to_str().unwrap()]).unwrap().eval;
        let e = args.evaluate_all().unwrap_err().to_string();
        assert!(e.contains("missing.jsonl"), "{e}");
    }
}
