//! The detector commands end to end through `pi3det-torch` (what `pi3det train / detect / demo`
//! run), at toy size: `demo` (simulate, train one epoch, evaluate per platform, adapt to the drone
//! and the quadruped) and its `--reuse`
//! rules, `--seeds` with the mean ± std table, then `detect` on the demo's checkpoint and the
//! evaluator on the files detect wrote; earlier output kept unless `--overwrite`; and clear errors
//! for a missing checkpoint. (`pi3det` handing these commands over is tested in crates/cli.)

use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;

fn torch(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pi3det-torch"))
        .args(args)
        .env("PI3DET_TORCH_THREADS", "1")
        .output()
        .expect("run pi3det-torch")
}

fn ok(out: &Output, what: &str) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{what} failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

/// A toy demo: one training and one validation sequence per platform of four frames, `epochs`
/// epochs.
fn demo(dir: &Path, epochs: &str, extra: &[&str]) -> (String, Value) {
    let d = s(dir);
    let base = [
        "demo",
        "--out",
        &d,
        "--train-sequences",
        "1",
        "--val-sequences",
        "1",
        "--target-train-sequences",
        "1",
        "--frames",
        "4",
        "--epochs",
        epochs,
        "--device",
        "cpu",
    ];
    let out = ok(&torch(&[&base[..], extra].concat()), "demo");
    let json = serde_json::from_slice(&std::fs::read(dir.join("demo.json")).unwrap()).unwrap();
    (out, json)
}

fn reused(json: &Value) -> (bool, bool) {
    let run = &json["seeds"][0];
    (run["reused_data"].as_bool().unwrap(), run["reused_checkpoint"].as_bool().unwrap())
}

fn evaluate(gt: &Path, det: &Path) -> pi3det_eval::EvalReport {
    let ds = pi3det_data::open(&gt.join("pi3det_infos_val.pkl")).unwrap();
    let dets = pi3det_eval::Detections::read(det).unwrap();
    pi3det_eval::evaluate_dataset(ds.as_ref(), &dets, &pi3det_eval::EvalOptions::default()).unwrap()
}

#[test]
fn demo_then_detect_then_eval() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (out, json) = demo(dir, "1", &["--seed", "3"]);
    for platform in ["vehicle", "drone", "quadruped"] {
        assert!(out.contains(&format!("| {platform} |")), "no {platform} row in\n{out}");
        assert!(dir.join(format!("eval_{platform}.json")).is_file());
    }
    assert!(out.contains("simulate") && out.contains("train") && out.contains("evaluate"), "no timings in\n{out}");
    assert_eq!(json["seeds"].as_array().map(Vec::len), Some(1));
    assert_eq!(json["seeds"][0]["seed"], 3);
    // The three platforms, then the drone and the quadruped after Pi3DET-Net's adaptation.
    assert_eq!(json["seeds"][0]["rows"].as_array().map(Vec::len), Some(5));
    for platform in ["drone", "quadruped"] {
        assert!(out.contains(&format!("| {platform} + Pi3DET-Net |")), "no adapted {platform} row in\n{out}");
        assert!(dir.join(format!("pi3det_net_{platform}/adapt.json")).is_file());
        // The source-only row is the demo's own evaluation of the same model, not a second one.
        let adapt: Value =
            serde_json::from_slice(&std::fs::read(dir.join(format!("pi3det_net_{platform}/adapt.json"))).unwrap())
                .unwrap();
        let row = json["seeds"][0]["rows"].as_array().unwrap().iter().find(|r| r["platform"] == platform).unwrap();
        assert_eq!(adapt["source_only"], row["summary"], "{platform}");
        assert!(!dir.join(format!("pi3det_net_{platform}/val_source_only.jsonl")).exists());
        // Nor the VPP diagnostics (PA through VPP, pseudo-labels without VPP).
        assert!(!dir.join(format!("pi3det_net_{platform}/val_source_only_vpp.jsonl")).exists());
        assert!(adapt["source_only_vpp"].is_null(), "{platform}");
        assert!(adapt["pseudo_label_quality"].as_array().is_some_and(|q| q.len() <= 1), "{platform}");
    }
    assert_eq!(json["seeds"][0]["rows"][0]["frames"], 4, "one validation sequence of four frames");
    assert_eq!(reused(&json), (false, false));
    // The training seed is the demo's seed.
    let ckpt = dir.join("pointpillars_vehicle/final.safetensors");
    let cfg = std::fs::read_to_string(dir.join("pointpillars_vehicle/config.toml")).unwrap();
    assert!(cfg.contains("seed = 3"), "{cfg}");

    // --reuse takes what these settings made (the evaluation's frame limit is not one of them)…
    let (_, json) = demo(dir, "1", &["--seed", "3", "--reuse", "--max-val-frames", "2", "--ka-epochs", "0"]);
    assert_eq!(reused(&json), (true, true));
    assert_eq!(json["seeds"][0]["rows"][0]["frames"], 2);
    assert_eq!(json["seeds"][0]["timings"]["simulate_s"], 0.0);
    // …but not a checkpoint of another schedule, nor data of another seed.
    let (_, json) = demo(dir, "2", &["--seed", "3", "--reuse", "--ka-epochs", "0"]);
    assert_eq!(reused(&json), (true, false));
    let val_info = || std::fs::read(dir.join("data/vehicle/val/pi3det_infos_val.pkl")).unwrap();
    let val_of_seed_3 = val_info();
    let (_, json) = demo(dir, "2", &["--seed", "4", "--reuse", "--ka-epochs", "0"]);
    assert_eq!(reused(&json), (false, false));
    // The validation split has its own seed: another training seed leaves it as it was.
    assert_eq!(json["val_seed"], 1000);
    assert!(val_info() == val_of_seed_3, "the validation split changed with the training seed");
    let cfg = std::fs::read_to_string(dir.join("pointpillars_vehicle/config.toml")).unwrap();
    assert!(cfg.contains("seed = 4"), "{cfg}");
    // A config that differs only in post-processing keeps the checkpoint (the weights are the same).
    let preset = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/pi3det_net_cpu.toml");
    let text = std::fs::read_to_string(preset).unwrap();
    let post_only = dir.join("post_only.toml");
    std::fs::write(&post_only, text.replace("[detector.post.bev_fit]\n", "[detector.post.bev_fit]\nmin_points = 20\n"))
        .unwrap();
    let (_, json) = demo(dir, "2", &["--seed", "4", "--reuse", "--ka-epochs", "0", "--adapt-config", &s(&post_only)]);
    assert_eq!(reused(&json), (true, true));

    let val = dir.join("data/vehicle/val");
    let det = dir.join("det");
    let detect_args = ["detect", "--ckpt", &s(&ckpt), "--data", &s(&val), "--out", &s(&det), "--device", "cpu"];
    let out = ok(&torch(&detect_args), "detect");
    assert!(out.contains("latency per frame"), "{out}");
    for f in ["detections.jsonl", "result.pkl", "latency.json"] {
        assert!(det.join(f).is_file(), "detect did not write {f}");
    }
    // A second run into the same folder replaces nothing unless asked; nor does training into a
    // folder that holds a model.
    let again = torch(&detect_args);
    assert!(!again.status.success(), "detect replaced an earlier run's output");
    assert!(String::from_utf8_lossy(&again.stderr).contains("--overwrite"));
    ok(&torch(&[&detect_args[..], &["--overwrite"]].concat()), "detect --overwrite");
    // --post replaces the checkpoint's [post] table; a file that is not one is an error naming it.
    let post = dir.join("post.toml");
    std::fs::write(&post, "[post]\nscore_threshold = 0.2\n[post.ground_fit]\n[post.bev_fit]\n").unwrap();
    ok(&torch(&[&detect_args[..], &["--overwrite", "--post", &s(&post)]].concat()), "detect --post");
    std::fs::write(&post, "[post]\nscore_treshold = 0.2\n").unwrap();
    let bad = torch(&[&detect_args[..], &["--overwrite", "--post", &s(&post)]].concat());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("post.toml") && err.contains("score_treshold"), "{err}");
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/pointpillars_cpu.toml");
    let ckpt_dir = ckpt.parent().unwrap();
    let train =
        torch(&["train", "--config", &s(&config), "--data", &s(&val), "--out", &s(ckpt_dir), "--device", "cpu"]);
    assert!(!train.status.success(), "train replaced an earlier run's model");
    let err = String::from_utf8_lossy(&train.stderr);
    assert!(err.contains(".safetensors") && err.contains("--overwrite"), "{err}");
    assert!(ckpt.is_file());
    // train reads the config's frame limits; --max-frames / --max-val-frames override them.
    let text = std::fs::read_to_string(&config).unwrap();
    let limited = dir.join("limited.toml");
    std::fs::write(&limited, text.replace("[train]\n", "[train]\nmax_train_frames = 3\nmax_eval_frames = 1\n"))
        .unwrap();
    let (limited, train_dir, val_s) = (s(&limited), s(&dir.join("data/vehicle/train")), s(&val));
    let args =
        ["train", "--config", &limited, "--data", &train_dir, "--val", &val_s, "--epochs", "1", "--device", "cpu"];
    let pp = s(&dir.join("pp"));
    let pp2 = s(&dir.join("pp2"));
    let out = torch(&[&args[..], &["--out", &pp]].concat());
    ok(&out, "train");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("3 training frames, 1 validation frames"), "{err}");
    let out = torch(&[&args[..], &["--out", &pp2, "--max-frames", "2", "--max-val-frames", "2"]].concat());
    ok(&out, "train --max-frames");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("2 training frames, 2 validation frames"), "{err}");
    let saved = std::fs::read_to_string(dir.join("pp2/config.toml")).unwrap();
    assert!(saved.contains("max_train_frames = 2") && saved.contains("max_eval_frames = 2"), "{saved}");
    // Both files detect wrote read back to the same evaluation.
    let a = evaluate(&val, &det.join("result.pkl"));
    let b = evaluate(&val, &det.join("detections.jsonl"));
    assert_eq!(a.overall.num_frames, 4);
    assert_eq!(serde_json::to_value(&a.overall).unwrap(), serde_json::to_value(&b.overall).unwrap());

    // autolabel: two checkpoints × two views → fusion → tracking → a label set over the points.
    let al = dir.join("labels");
    let pp_ckpt = s(&dir.join("pp/final.safetensors"));
    let al_args = [
        "autolabel",
        "--data",
        &val_s,
        "--ckpt",
        &s(&ckpt),
        "--ckpt",
        &pp_ckpt,
        "--tta",
        "none,flip",
        "--out",
        &s(&al),
        "--device",
        "cpu",
        "--min-score",
        "0.0",
    ];
    let out = ok(&torch(&al_args), "autolabel");
    assert!(out.contains("| fused |") && out.contains("| tracked |"), "no quality rows in\n{out}");
    let report: Value = serde_json::from_slice(&std::fs::read(al.join("autolabel.json")).unwrap()).unwrap();
    assert_eq!(report["inputs"].as_array().map(Vec::len), Some(4));
    assert_eq!(report["frames"], 4);
    assert_eq!(std::fs::read_dir(al.join("detections")).unwrap().count(), 4);
    let original = pi3det_data::open(&val.join("pi3det_infos_val.pkl")).unwrap();
    let labelled = pi3det_data::open(&al.join("pi3det_infos_val.pkl")).unwrap();
    assert_eq!(labelled.len(), original.len());
    let labels = pi3det_eval::Detections::read(&al.join("labels.jsonl")).unwrap();
    for i in 0..labelled.len() {
        let (a, b) = (original.info(i).unwrap(), labelled.info(i).unwrap());
        // The points are the original files, untouched; the boxes are the final labels.
        assert_eq!(std::fs::canonicalize(&a.points_path).unwrap(), std::fs::canonicalize(&b.points_path).unwrap());
        assert_eq!(b.objects.len(), labels.frames.get(&b.id).map_or(0, Vec::len));
        assert_eq!((a.sequence, a.timestamp_s), (b.sequence, b.timestamp_s));
    }
    let again = torch(&al_args);
    assert!(!again.status.success() && String::from_utf8_lossy(&again.stderr).contains("--overwrite"));
}

#[test]
fn demo_over_seeds_prints_mean_and_std() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (out, json) = demo(dir, "1", &["--seeds", "0,1", "--max-val-frames", "2", "--ka-epochs", "0"]);
    assert!(out.contains("mean ± sample std"), "{out}");
    assert!(out.contains("| 1 | quadruped | 2 |"), "no per-seed row in\n{out}");
    assert!(out.contains(" ± "), "{out}");
    let seeds: Vec<u64> = json["seeds"].as_array().unwrap().iter().map(|r| r["seed"].as_u64().unwrap()).collect();
    assert_eq!(seeds, vec![0, 1]);
    for seed in [0, 1] {
        assert!(dir.join(format!("seed_{seed}/pointpillars_vehicle/final.safetensors")).is_file());
        assert!(dir.join(format!("seed_{seed}/eval_drone.json")).is_file());
    }
    let info = |seed: u64, split: &str| {
        std::fs::read(dir.join(format!("seed_{seed}/data/vehicle/{split}/pi3det_infos_{split}.pkl"))).unwrap()
    };
    assert!(info(0, "val") == info(1, "val"), "every seed is validated on the same frames");
    assert!(info(0, "train") != info(1, "train"), "each seed trains on its own frames");
    let summary = json["summary"].as_array().unwrap();
    assert_eq!(summary.len(), 3);
    let car = &summary[0]["classes"][0];
    assert_eq!((summary[0]["platform"].as_str(), car["class"].as_str()), (Some("vehicle"), Some("Car")));
    let bev = &car["bev"];
    if !bev.is_null() {
        let v: Vec<f64> = bev["values"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        assert!((bev["mean"].as_f64().unwrap() - mean).abs() < 1e-9);
        if v.len() == 2 {
            let std = (v[0] - v[1]).abs() / 2f64.sqrt();
            assert!((bev["std"].as_f64().unwrap() - std).abs() < 1e-9);
        }
    }
    assert!(json["timings"]["total_s"].as_f64().unwrap() > 0.0);
}

#[test]
fn missing_checkpoint_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("nope.safetensors");
    let out = torch(&[
        "detect",
        "--ckpt",
        missing.to_str().unwrap(),
        "--data",
        tmp.path().to_str().unwrap(),
        "--out",
        tmp.path().join("o").to_str().unwrap(),
        "--device",
        "cpu",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope.safetensors"), "error does not name the file: {err}");
    assert!(!err.contains("panicked"), "{err}");
}
