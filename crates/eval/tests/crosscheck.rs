//! Peer check against the reference evaluator (mmdet3d's copy of the KITTI python evaluator,
//! run under the CUDA simulator) on a few small seeded cases: the Python scripts write the cases
//! and the reference's numbers, this test evaluates the same files with the library.
//!
//! Needs `.venv-crosscheck` at the repository root (`scripts/crosscheck_eval/setup.sh`); without
//! it the test prints a notice and passes. Larger runs: `scripts/crosscheck_eval/crosscheck.py`,
//! `e2e.py` and `bench.py`.

use std::path::{Path, PathBuf};
use std::process::Command;

use pi3det_eval::classes::default_overlaps;
use pi3det_eval::{
    default_compute_aos, evaluate_dataset, evaluate_kitti, ClassSpec, Detections, EvalOptions, GroupResult, KittiFrame,
};
use serde_json::Value;

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> Option<PathBuf> {
    let p = repo_root().join(".venv-crosscheck/bin/python");
    p.exists().then_some(p)
}

fn run_script(py: &Path, script: &str, args: &[&str]) {
    let out = Command::new(py)
        .arg(repo_root().join("scripts/crosscheck_eval").join(script))
        .args(args)
        .env("NUMBA_ENABLE_CUDASIM", "1")
        .output()
        .expect("run the cross-check script");
    assert!(
        out.status.success(),
        "{script} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Compares every AP with the reference's layout `{class: [set]{metric: {r11, r40}}}`.
fn compare(label: &str, ours: &GroupResult, reference: &Value) -> usize {
    let mut bad = Vec::new();
    let mut n = 0;
    for c in &ours.classes {
        for (s, set) in c.sets.iter().enumerate() {
            for (m, ap) in
                [("bbox", Some(&set.bbox)), ("bev", Some(&set.bev)), ("3d", Some(&set.d3)), ("aos", set.aos.as_ref())]
            {
                let Some(ap) = ap else {
                    bad.push(format!("{} set {s} {m}: not computed", c.class));
                    continue;
                };
                for (kind, ours) in [("r11", ap.r11), ("r40", ap.r40)] {
                    for d in 0..3 {
                        let r = reference[&c.class][s][m][kind][d].as_f64().unwrap_or(f64::NAN);
                        n += 1;
                        let same = if r.is_nan() || ours[d].is_nan() {
                            r.is_nan() && ours[d].is_nan()
                        } else {
                            (r - ours[d]).abs() <= 1e-4
                        };
                        if !same {
                            bad.push(format!(
                                "{} set {s} {m} {kind} difficulty {d}: reference {r} ours {}",
                                c.class, ours[d]
                            ));
                        }
                    }
                }
            }
        }
    }
    assert!(bad.is_empty(), "{label}: {} of {n} APs differ from the reference:\n{}", bad.len(), bad.join("\n"));
    n
}

fn specs(classes: &Value) -> Vec<ClassSpec> {
    classes
        .as_array()
        .expect("class list")
        .iter()
        .map(|c| {
            let name = c.as_str().expect("class name").to_string();
            ClassSpec { overlaps: default_overlaps(&name).expect("KITTI class"), name }
        })
        .collect()
}

fn read_json<T: serde::de::DeserializeOwned>(p: &Path) -> T {
    serde_json::from_str(&std::fs::read_to_string(p).expect("read")).expect("parse")
}

#[test]
fn agrees_with_the_reference_evaluator() {
    let Some(py) = python() else {
        // CI installs the venv (scripts/test), so there a missing one is a failure, not a skip.
        assert!(
            std::env::var_os("CI").is_none(),
            ".venv-crosscheck not found at the repository root in CI: scripts/crosscheck_eval/setup.sh failed"
        );
        eprintln!("notice: .venv-crosscheck not found at the repository root; run scripts/crosscheck_eval/setup.sh to cross-check against the reference evaluator");
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let core = dir.path().join("core");
    let e2e = dir.path().join("e2e");
    let (core_s, e2e_s) = (core.to_str().expect("utf-8 path"), e2e.to_str().expect("utf-8 path"));
    run_script(
        &py,
        "crosscheck.py",
        &["--seed", "11", "--cases", "2", "--frames", "25", "--reference-only", "--keep", core_s],
    );
    run_script(&py, "e2e.py", &["--seed", "11", "--cases", "1", "--frames", "12", "--reference-only", "--out", e2e_s]);

    let mut compared = 0;
    for c in 0..2 {
        let case = core.join(format!("case_{c:03}"));
        let gt: Vec<KittiFrame> = read_json(&case.join("gt.json"));
        let dt: Vec<KittiFrame> = read_json(&case.join("dt.json"));
        let reference: Value = read_json(&case.join("reference.json"));
        let r =
            evaluate_kitti("all", &gt, &dt, &specs(&reference["classes"]), default_compute_aos(&dt)).expect("evaluate");
        compared += compare(&format!("core case {c}"), &r, &reference["reference"]);
    }
    let manifest: Vec<Value> = read_json(&e2e.join("manifest.json"));
    assert_eq!(manifest.len(), 5, "kitti txt/jsonl/pkl and pi3det jsonl/pkl");
    for run in &manifest {
        let label = run["label"].as_str().unwrap_or("?");
        let ds = pi3det_data::open(Path::new(run["gt"].as_str().expect("gt path"))).expect("open ground truth");
        let dets = Detections::read(Path::new(run["det"].as_str().expect("det path"))).expect("read detections");
        let classes = specs(&run["classes"]).into_iter().map(|c| c.name).collect();
        let opts = EvalOptions { classes, per_platform: false, per_sequence: false, ..EvalOptions::default() };
        let r = evaluate_dataset(ds.as_ref(), &dets, &opts).expect("evaluate");
        compared += compare(label, &r.overall, &run["reference"]);
    }
    eprintln!("{compared} APs agree with the reference evaluator");
}
