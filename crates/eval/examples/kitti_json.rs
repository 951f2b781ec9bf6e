//! Evaluates ground truth and detections given as JSON lists of frames in the reference's
//! camera-frame annotation form (`KittiFrame`), and prints the result as JSON. Used by the
//! cross-check (`scripts/crosscheck_eval/`), which feeds the reference the same files.
//!
//! `cargo run --release -p pi3det-eval --example kitti_json -- GT.json DT.json [Car,Pedestrian]`

use std::path::Path;
use std::time::Instant;

use pi3det_eval::{classes::default_overlaps, default_compute_aos, evaluate_kitti, ClassSpec, KittiFrame};

fn read(path: &str) -> Result<Vec<KittiFrame>, String> {
    let text = std::fs::read_to_string(Path::new(path)).map_err(|e| format!("{path}: {e}"))?;
    serde_json::from_str(&text).map_err(|e| format!("{path}: {e}"))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        eprintln!("usage: kitti_json GT.json DT.json [CLASS,CLASS,...]");
        std::process::exit(2);
    }
    let run = || -> Result<(), String> {
        let gt = read(&args[0])?;
        let dt = read(&args[1])?;
        let names = args.get(2).map(String::as_str).unwrap_or("Car,Pedestrian,Cyclist");
        let classes = names
            .split(',')
            .map(|n| {
                default_overlaps(n)
                    .map(|overlaps| ClassSpec { name: n.to_string(), overlaps })
                    .ok_or_else(|| format!("no default overlaps for {n}"))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let t = Instant::now();
        let r = evaluate_kitti("all", &gt, &dt, &classes, default_compute_aos(&dt)).map_err(|e| e.to_string())?;
        let secs = t.elapsed().as_secs_f64();
        let mut v = serde_json::to_value(&r).map_err(|e| e.to_string())?;
        v["eval_seconds"] = secs.into();
        println!("{v}");
        Ok(())
    };
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}
