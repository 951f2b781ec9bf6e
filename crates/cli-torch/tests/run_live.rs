//! `pi3det run` end to end through `pi3det-torch`: a loopback replayer sends a faulty Ouster
//! packet stream (loss, reordering, duplicates, garbage, a frame-id wrap) and the command writes
//! one detection line per completed sweep, readable by the evaluator; a ROS 2 bag and a dataset
//! folder (with VPP) as sources; an MCAP sink; bad input named, earlier output kept.

use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use pi3det_live::replay::{self, Faults, ReplayPlan};
use pi3det_live::source::mcap_bag::write_bag;
use pi3det_live::source::pointcloud2::from_xyzi;
use pi3det_nn::checkpoint::{self, TrainState};
use pi3det_sequence::synth::{metadata_json, SynthSpec};

fn torch() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_pi3det-torch"));
    c.env("PI3DET_TORCH_THREADS", "1");
    c
}

fn ok(out: &Output, what: &str) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{what} failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}

/// An untrained PointPillars CPU-preset checkpoint with a score threshold that lets its
/// boxes through (the test is about the stream, not accuracy).
fn checkpoint(dir: &Path) -> PathBuf {
    let cfg_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/pointpillars_cpu.toml");
    let cfg = pi3det_nn::DetectorConfig::from_file(&cfg_path).unwrap();
    let det = pi3det_nn::Detector::new(&cfg, tch::Device::Cpu).unwrap();
    let path = dir.join("untrained.safetensors");
    checkpoint::save(&path, &det, None, &TrainState::default()).unwrap();
    path
}

fn lines(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

fn spec() -> SynthSpec {
    SynthSpec { columns: 512, ..SynthSpec::os1_64("t", 1) }
}

#[test]
fn udp_stream_gives_one_line_per_completed_sweep() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let ckpt = checkpoint(dir);
    let md = dir.join("meta.json");
    std::fs::write(&md, metadata_json(&spec())).unwrap();
    // A free port: bound, read, released (the command binds it again).
    let port = UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let source = format!("ouster-udp://127.0.0.1:{port}?metadata={}&timeout_s=2", md.display());
    let (jsonl, mcap, report) = (dir.join("det.jsonl"), dir.join("det.mcap"), dir.join("report.json"));
    let mut child = torch()
        .args(["run", "--ckpt", ckpt.to_str().unwrap(), "--source", &source, "--queue", "64", "--device", "cpu"])
        .args([
            "--sink",
            jsonl.to_str().unwrap(),
            "--sink",
            mcap.to_str().unwrap(),
            "--report",
            report.to_str().unwrap(),
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Send once the command listens: it prints "run: SOURCE → SINKS" after binding the port.
    let stderr = child.stderr.take().unwrap();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in std::io::BufRead::lines(std::io::BufReader::new(stderr)).map_while(Result::ok) {
            if line.starts_with("run: ") {
                let _ = ready_tx.send(());
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let listening = ready_rx.recv_timeout(std::time::Duration::from_secs(120)).is_ok();
    let faults = Faults { loss: 0.03, reorder: 0.05, duplicate: 0.05, truncate: 0.0, garbage: 0.05 };
    let plan = ReplayPlan { sweeps: 6, first_frame_id: 65533, restart_at: None, faults, seed: 5 };
    if listening {
        replay::send(&replay::datagrams(&spec(), &plan), format!("127.0.0.1:{port}").parse().unwrap(), 5.0).unwrap();
    }
    let out = child.wait_with_output().unwrap();
    let stderr = reader.join().unwrap();
    assert!(listening && out.status.success(), "run failed:\n{}\n{stderr}", String::from_utf8_lossy(&out.stdout));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let sweeps = r["source"]["sweeps"].as_u64().unwrap();
    assert!((5..=6).contains(&sweeps), "{stdout}");
    assert_eq!(r["processed"].as_u64(), Some(sweeps), "a 64-deep queue drops nothing: {stdout}");
    assert_eq!(r["source"]["counters"]["wraps"], 1, "{stdout}");
    assert!(r["source"]["counters"]["duplicate"].as_u64().unwrap() > 0);
    let l = lines(&jsonl);
    assert_eq!(l.len() as u64, sweeps);
    for line in &l {
        assert!(line["timestamp_s"].as_f64().unwrap() > 0.0);
        assert!(line["latency_ms"]["total"].as_f64().unwrap() > 0.0);
        assert_eq!(line["names"].as_array().unwrap().len(), line["boxes_lidar"].as_array().unwrap().len());
    }
    // What `pi3det eval` reads.
    let dets = pi3det_eval::Detections::read(&jsonl).unwrap();
    assert_eq!(dets.frames.len() as u64, sweeps);
    assert!(stdout.contains("p99"), "{stdout}");
    let bytes = std::fs::read(&mcap).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert_eq!(summary.stats.unwrap().message_count, 2 * sweeps, "a scene update and a cloud per sweep");
}

#[test]
fn bag_and_dataset_sources_and_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let ckpt = ckpt_str(dir);
    // A ROS 2 bag of three clouds (written with our CDR encoder and the mcap crate).
    let bag = dir.join("b.mcap");
    let clouds: Vec<_> = (0..3u64)
        .map(|k| {
            let pts: Vec<[f32; 4]> =
                (0..500).map(|i| [5.0 + (i % 50) as f32 * 0.5, -10.0 + (i / 50) as f32, -1.5, 0.3]).collect();
            from_xyzi(&pts, (k + 1) * 100_000_000, "lidar")
        })
        .collect();
    write_bag(&bag, "/points", &clouds).unwrap();
    let jsonl = dir.join("bag.jsonl");
    let run = |source: &str, sink: &Path, extra: &[&str]| {
        torch()
            .args(["run", "--ckpt", &ckpt, "--source", source, "--sink", sink.to_str().unwrap(), "--device", "cpu"])
            .args(extra)
            .output()
            .unwrap()
    };
    let src = format!("mcap://{}?topic=/points", bag.display());
    ok(&run(&src, &jsonl, &[]), "run on a bag");
    assert_eq!(lines(&jsonl).len(), 3);
    // Existing output is kept.
    let before = std::fs::read(&jsonl).unwrap();
    let again = run(&src, &jsonl, &[]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--overwrite"));
    assert_eq!(std::fs::read(&jsonl).unwrap(), before);
    // A topic that is not there, named with the ones that are.
    let bad = run(&format!("mcap://{}?topic=/velodyne_points", bag.display()), &dir.join("x.jsonl"), &[]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("no topic '/velodyne_points'") && err.contains("/points"), "{err}");
    assert!(!dir.join("x.jsonl").exists(), "nothing written on a bad source");
    // Real Pi3DET-layout frames with VPP (ground estimated per frame), two frames at most.
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/pi3det_sample");
    if !data.exists() {
        eprintln!("SKIP: {} missing", data.display());
        return;
    }
    let out = dir.join("vpp.jsonl");
    let stdout = ok(&run(data.to_str().unwrap(), &out, &["--vpp-height", "1.9", "--max-frames", "2"]), "run with VPP");
    assert_eq!(lines(&out).len(), 2, "{stdout}");
}

fn ckpt_str(dir: &Path) -> String {
    checkpoint(dir).to_str().unwrap().to_string()
}

#[test]
fn an_exported_torchscript_model_runs_with_the_same_detections() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let ckpt = ckpt_str(dir);
    let model = dir.join("m.pt");
    let export = |extra: &[&str]| {
        torch()
            .args(["export", "--ckpt", &ckpt, "--out", model.to_str().unwrap(), "--device", "cpu"])
            .args(extra)
            .output()
            .unwrap()
    };
    ok(&export(&[]), "export");
    assert!(dir.join("m.json").is_file());
    let again = export(&[]);
    assert!(!again.status.success() && String::from_utf8_lossy(&again.stderr).contains("--overwrite"));
    let onnx = export(&["--format", "onnx", "--overwrite"]);
    assert!(!onnx.status.success() && String::from_utf8_lossy(&onnx.stderr).contains("ONNX"));
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/pi3det_sample");
    if !data.exists() {
        eprintln!("SKIP: {} missing", data.display());
        return;
    }
    let run = |m: &str, out: &Path| {
        ok(
            &torch()
                .args(["run", "--ckpt", m, "--source", data.to_str().unwrap(), "--sink", out.to_str().unwrap()])
                .args(["--max-frames", "2", "--score-threshold", "0", "--device", "cpu"])
                .output()
                .unwrap(),
            "run",
        )
    };
    let (a, b) = (dir.join("a.jsonl"), dir.join("b.jsonl"));
    run(&ckpt, &a);
    run(model.to_str().unwrap(), &b);
    let strip = |p: &Path| -> Vec<serde_json::Value> {
        lines(p)
            .into_iter()
            .map(|mut l| {
                l.as_object_mut().unwrap().remove("latency_ms");
                l
            })
            .collect()
    };
    let (la, lb) = (strip(&a), strip(&b));
    assert_eq!(la.len(), 2);
    assert!(la.iter().any(|l| !l["names"].as_array().unwrap().is_empty()), "nothing detected, nothing compared");
    assert_eq!(la, lb, "checkpoint and TorchScript model disagree");
}

#[test]
fn pytorch_runs_the_exported_model_with_rusts_output() {
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let has_torch = Command::new(&py).args(["-c", "import torch, numpy"]).output().is_ok_and(|o| o.status.success());
    if !has_torch {
        eprintln!(
            "SKIP: {} cannot import torch (scripts/setup-torch --python installs its dependencies)",
            py.display()
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let ckpt = ckpt_str(tmp.path());
    let model = tmp.path().join("m.pt");
    ok(
        &torch()
            .args(["export", "--ckpt", &ckpt, "--out", model.to_str().unwrap(), "--device", "cpu"])
            .output()
            .unwrap(),
        "export",
    );
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/torchscript/run_exported.py");
    let out = Command::new(&py).arg(script).arg(&model).output().unwrap();
    let stdout = ok(&out, "run_exported.py");
    assert!(stdout.contains("max |python - rust|"), "{stdout}");
}
