//! `scripts/ray_benchmark.py` on a local Ray instance bound to 127.0.0.1: one Ray task per cell
//! (each running `pi3det-torch bench suite --only CELL`), the cells' folders gathered and merged,
//! give the table of one unsharded in-process run. Skipped with a message where Ray could not be
//! installed (`scripts/setup-ray`).

mod common;

use std::path::Path;
use std::process::Command;

use common::{aps, args, write_suite, TORCH_RNG};
use pi3det_cli_torch::benchmark::{self, suite::Suite};

#[test]
fn ray_driver_runs_every_cell_and_merges_to_the_unsharded_table() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let python = root.join(".venv-ray/bin/python");
    let has_ray =
        python.is_file() && Command::new(&python).args(["-c", "import ray"]).output().is_ok_and(|o| o.status.success());
    if !has_ray {
        eprintln!("SKIP: Ray is not installed (scripts/setup-ray puts it in .venv-ray)");
        return;
    }
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let suite = write_suite(dir.path(), &["source_only", "st3d", "target_only"], 1);
    let whole = benchmark::run(&args(&suite, &dir.path().join("whole"))).unwrap();
    let out = dir.path().join("ray");
    let o = Command::new(&python)
        .arg(root.join("scripts/ray_benchmark.py"))
        .args(["--suite", suite.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--pi3det", env!("CARGO_BIN_EXE_pi3det-torch"), "--num-cpus", "2", "--torch-threads", "1"])
        // Ray's own temp files stay inside the test's folder.
        .env("RAY_TMPDIR", dir.path())
        .output()
        .unwrap();
    let log = format!("{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{log}");
    assert_eq!(log.matches(": done").count(), 3, "{log}");
    let s = Suite::from_file(&suite).unwrap();
    let merged = benchmark::collect(&s, &out);
    assert_eq!(aps(&merged), aps(&whole), "{log}");
    assert!(out.join("benchmark.md").is_file());
}
