//! The detector commands end to end through the binary, at toy size: `pi3det demo` (simulate,
//! train one epoch, evaluate per platform), then `pi3det detect` on its checkpoint and `pi3det
//! eval` on the files detect wrote; earlier output kept unless `--overwrite`; and clear errors
//! for a missing checkpoint.
#![cfg(feature = "nn")]

use std::path::Path;
use std::process::{Command, Output};

fn pi3det(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pi3det")).args(args).env("PI3DET_TORCH_THREADS", "1").output().expect("run pi3det")
}

fn ok(out: &Output, what: &str) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{what} failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}

#[test]
fn demo_then_detect_then_eval() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let demo = ok(
        &pi3det(&[
            "demo",
            "--out",
            &s(dir),
            "--vehicle-sequences",
            "2",
            "--other-sequences",
            "2",
            "--frames",
            "4",
            "--epochs",
            "1",
            "--device",
            "cpu",
        ]),
        "demo",
    );
    for platform in ["vehicle", "drone", "quadruped"] {
        assert!(demo.contains(&format!("| {platform} |")), "no {platform} row in\n{demo}");
        assert!(dir.join(format!("eval_{platform}.json")).is_file());
    }
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("demo.json")).unwrap()).unwrap();
    assert_eq!(rows.as_array().map(Vec::len), Some(3));

    let ckpt = dir.join("pointpillars_vehicle/final.safetensors");
    let val = dir.join("data/vehicle/val");
    let det = dir.join("det");
    let detect_args = ["detect", "--ckpt", &s(&ckpt), "--data", &s(&val), "--out", &s(&det), "--device", "cpu"];
    let out = ok(&pi3det(&detect_args), "detect");
    assert!(out.contains("latency per frame"), "{out}");
    for f in ["detections.jsonl", "result.pkl", "latency.json"] {
        assert!(det.join(f).is_file(), "detect did not write {f}");
    }
    // A second run into the same folder replaces nothing unless asked; nor does training into a
    // folder that holds a model.
    let again = pi3det(&detect_args);
    assert!(!again.status.success(), "detect replaced an earlier run's output");
    assert!(String::from_utf8_lossy(&again.stderr).contains("--overwrite"));
    ok(&pi3det(&[&detect_args[..], &["--overwrite"]].concat()), "detect --overwrite");
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/pointpillars_cpu.toml");
    let ckpt_dir = ckpt.parent().unwrap();
    let train =
        pi3det(&["train", "--config", &s(&config), "--data", &s(&val), "--out", &s(ckpt_dir), "--device", "cpu"]);
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
    let out = pi3det(&[&args[..], &["--out", &pp]].concat());
    ok(&out, "train");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("3 training frames, 1 validation frames"), "{err}");
    let out = pi3det(&[&args[..], &["--out", &pp2, "--max-frames", "2", "--max-val-frames", "2"]].concat());
    ok(&out, "train --max-frames");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("2 training frames, 2 validation frames"), "{err}");
    let saved = std::fs::read_to_string(dir.join("pp2/config.toml")).unwrap();
    assert!(saved.contains("max_train_frames = 2") && saved.contains("max_eval_frames = 2"), "{saved}");
    for f in ["result.pkl", "detections.jsonl"] {
        let out = ok(&pi3det(&["eval", "--gt", &s(&val), "--det", &s(&det.join(f)), "--json"]), "eval");
        let _: serde_json::Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("eval --json: {e}\n{out}"));
    }
}

#[test]
fn missing_checkpoint_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("nope.safetensors");
    let out = pi3det(&[
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
