//! Helpers shared by the benchmark tests: a tiny detector and a tiny simulated suite.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use pi3det_adapt::pipeline::AdaptConfig;
use pi3det_cli_torch::benchmark::table::CellResult;
use pi3det_cli_torch::benchmark::BenchmarkArgs;
use pi3det_cli_torch::DeviceArgs;
use pi3det_nn::config::PostConfig;
use pi3det_nn::device::DeviceChoice;
use pi3det_nn::testing::tiny_roi_head;
use pi3det_nn::DetectorConfig;

/// libtorch's generator is one per process: tests that train take turns (the shard test compares
/// trained weights' results exactly).
pub static TORCH_RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

pub fn tiny_detector() -> DetectorConfig {
    DetectorConfig {
        roi_head: Some(tiny_roi_head()),
        // An untrained detector scores low: keep its boxes so the self-training paths see labels.
        post: PostConfig { score_threshold: 0.01, ..PostConfig::default() },
        ..pi3det_nn::testing::tiny_detector(25.6, 0.8)
    }
}

pub fn tiny_adapt() -> AdaptConfig {
    let base = AdaptConfig::default();
    let mut detector = tiny_detector();
    detector.train.augment = base.detector.train.augment.clone();
    detector.neck = base.detector.neck.clone();
    detector.pfa =
        Some(pi3det_nn::roi_heads::pfa::PfaConfig { latent_channels: 8, hidden_channels: 16, ..Default::default() });
    let mut cfg = AdaptConfig { name: "tiny".into(), detector, ..base };
    cfg.ka.epochs = 1;
    cfg.pseudo_labels.positive_score = 0.02;
    cfg.pseudo_labels.ignore_score = 0.01;
    cfg
}

/// Self-training with thresholds an untrained model reaches.
const LOW: &str =
    "self_training = { epochs = 1, labels = { positive_score = 0.02, ignore_score = 0.01, refresh_every = 1 } }";

pub fn write_suite(dir: &Path, methods: &[&str], st3d_epochs: usize) -> PathBuf {
    std::fs::write(dir.join("det.toml"), tiny_detector().to_toml()).unwrap();
    std::fs::write(dir.join("net.toml"), tiny_adapt().to_toml()).unwrap();
    let mut s = String::from(
        "name = \"tiny\"\nseed = 1\n[detectors.tiny]\nconfig = \"det.toml\"\npi3det_net = \"net.toml\"\n\
         [datasets.veh]\nsim = { platform = \"vehicle\", sequences = 2, val_sequences = 1, frames = 3 }\n\
         [datasets.quad]\nsim = { platform = \"quadruped\", sequences = 2, val_sequences = 1, frames = 3, val_seed = 7 }\n\
         [[tasks]]\nname = \"v2q\"\nsource = \"veh\"\ntarget = \"quad\"\n\
         [schedule]\nepochs = 1\nadapt_epochs = 1\nmatch_sensor_height = true\nequal_steps = true\n",
    );
    for m in methods {
        s += &format!("[[methods]]\nkind = \"{m}\"\n");
        match *m {
            "st3d" => s += &LOW.replace("epochs = 1,", &format!("epochs = {st3d_epochs},")),
            "st3d_pp" => {
                s += &LOW.replace("refresh_every = 1 }", "refresh_every = 1 }, source_assisted = true, ds_norm = true")
            }
            "redb" | "ms3d_pp" => s += LOW,
            _ => {}
        }
        s += "\n";
    }
    let p = dir.join("suite.toml");
    std::fs::write(&p, s).unwrap();
    p
}

pub fn args(suite: &Path, out: &Path) -> BenchmarkArgs {
    BenchmarkArgs {
        suite: suite.to_path_buf(),
        out: out.to_path_buf(),
        only: Vec::new(),
        shard: None,
        merge: Vec::new(),
        list: false,
        force: false,
        seeds: Vec::new(),
        bootstrap: 20,
        device: DeviceArgs { device: DeviceChoice::Cpu, torch_threads: Some(1), precision: None },
    }
}

/// Each cell's AP as JSON, sorted by cell id.
pub fn aps(results: &[CellResult]) -> Vec<(String, String)> {
    let mut v: Vec<(String, String)> =
        results.iter().map(|r| (r.id.clone(), serde_json::to_string(&r.ap).unwrap())).collect();
    v.sort();
    v
}
