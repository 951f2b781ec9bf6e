//! Times the evaluation of a KITTI-val-sized synthetic split (3,769 frames, ~15 ground truths
//! and 30 detections per frame, Car + Pedestrian, fake KITTI fields as for Pi3DET) and of the
//! issue's 2,000-frame / 30k GT / 30k detection case.
//!
//! `cargo run --release -p pi3det-eval --example synthetic_bench [-- FRAMES GT_PER_FRAME DET_PER_FRAME [--write DIR]]`
//!
//! `--write DIR` also writes the split as files (DIR/pi3det_infos_val.pkl, DIR/det.jsonl,
//! DIR/result.pkl) to time `pi3det eval` on them, process start and reading included.

mod common;

use std::time::Instant;

use std::path::Path;

use pi3det_data::pickle::{self, NdArray, Value};
use pi3det_eval::{evaluate, format_paper, EvalOptions, JsonlFrame};

fn write(s: &common::synthetic::Split, dir: &Path) {
    std::fs::create_dir_all(dir).expect("output folder");
    let infos: Vec<Value> =
        s.gt.iter()
            .map(|f| {
                let n = f.objects.len();
                let boxes: Vec<f32> = f.objects.iter().flat_map(|o| o.box3d.to_array().map(|v| v as f32)).collect();
                Value::dict([
                    ("frame_id", Value::from(f.id.as_str())),
                    ("platform", Value::from("vehicle")),
                    (
                        "annos",
                        Value::dict([
                            (
                                "gt_names",
                                NdArray::from_vec(f.objects.iter().map(|o| o.name.clone()).collect::<Vec<_>>()).into(),
                            ),
                            ("gt_boxes_lidar", NdArray::new(vec![n, 7], boxes).expect("shape").into()),
                        ]),
                    ),
                ])
            })
            .collect();
    pickle::to_path(dir.join("pi3det_infos_val.pkl"), &Value::List(infos), true).expect("write infos");
    let mut jsonl = String::new();
    let mut results = Vec::new();
    for (id, dets) in &s.dets.frames {
        let n = dets.len();
        let line = JsonlFrame {
            frame_id: id.clone(),
            names: dets.iter().map(|d| d.name.clone()).collect(),
            scores: dets.iter().map(|d| d.score).collect(),
            boxes_lidar: dets.iter().map(|d| d.lidar.expect("lidar box").to_array()).collect(),
            bbox: None,
            alpha: None,
            track_ids: None,
            timestamp_s: None,
            latency_ms: None,
        };
        jsonl.push_str(&serde_json::to_string(&line).expect("json"));
        jsonl.push('\n');
        let boxes: Vec<f32> = line.boxes_lidar.iter().flat_map(|b| b.map(|v| v as f32)).collect();
        results.push(Value::dict([
            ("frame_id", Value::from(id.as_str())),
            ("name", NdArray::from_vec(line.names.clone()).into()),
            ("score", NdArray::from_vec(line.scores.iter().map(|&v| v as f32).collect::<Vec<_>>()).into()),
            ("boxes_lidar", NdArray::new(vec![n, 7], boxes).expect("shape").into()),
        ]));
    }
    std::fs::write(dir.join("det.jsonl"), jsonl).expect("write jsonl");
    pickle::to_path(dir.join("result.pkl"), &Value::List(results), true).expect("write result.pkl");
    println!("wrote {}/{{pi3det_infos_val.pkl, det.jsonl, result.pkl}}", dir.display());
}

fn time(frames: usize, gt: usize, det: usize, out: Option<&Path>) {
    let s = common::synthetic::split(7, frames, gt, det);
    if let Some(dir) = out {
        write(&s, dir);
    }
    let ngt: usize = s.gt.iter().map(|f| f.objects.len()).sum();
    let opts = EvalOptions { classes: vec!["Car".into(), "Pedestrian".into()], ..EvalOptions::default() };
    // One warm-up (thread pool start), then the best of three.
    let mut best = f64::INFINITY;
    let mut report = None;
    for _ in 0..4 {
        let t = Instant::now();
        let r = evaluate(&s.gt, &s.dets, &opts).expect("evaluation");
        best = best.min(t.elapsed().as_secs_f64());
        report = Some(r);
    }
    println!(
        "{frames} frames, {ngt} GT, {} detections: {:.3} s (best of 3, {} threads)",
        s.dets.num_detections(),
        best,
        rayon::current_num_threads()
    );
    print!("{}", format_paper(&report.expect("ran").overall));
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = args.iter().position(|a| a == "--write").and_then(|i| args.get(i + 1)).map(Path::new);
    let a: Vec<usize> = args.iter().filter_map(|x| x.parse().ok()).collect();
    if a.len() == 3 {
        time(a[0], a[1], a[2], out);
    } else {
        time(3769, 15, 30, None);
        time(2000, 15, 15, None);
    }
}
