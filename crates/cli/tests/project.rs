//! `pi3det project` from the command line: the summary line, the exit status on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn pi3det(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pi3det")).args(args).output().expect("run pi3det")
}

fn nuscenes() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/nuscenes_demo");
    assert!(p.exists(), "{} is missing (the test data beside the repository)", p.display());
    p
}

#[test]
fn project_prints_the_summary_and_refuses_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("images");
    let (data, out_s) = (nuscenes(), out.to_str().unwrap().to_string());
    let args = ["project", "--data", data.to_str().unwrap(), "--out", &out_s, "--camera", "CAM_FRONT"];
    let r = pi3det(&args);
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&r.stderr));
    assert!(stdout.starts_with("1 frames, 1 images: 69 boxes (69 gt, 0 det): "), "{stdout}");
    assert!(out.join("projection_report.json").exists());
    // Again without --overwrite: refused, with exit status 1.
    let r = pi3det(&args);
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("--overwrite"));
    let r =
        pi3det(&["project", "--data", data.to_str().unwrap(), "--out", &out_s, "--overwrite", "--camera", "CAM_UP"]);
    assert_eq!(r.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(stderr.contains("--camera CAM_UP") && stderr.contains("CAM_BACK_RIGHT"), "{stderr}");
    let r = pi3det(&["project", "--data", data.to_str().unwrap(), "--out", &out_s, "--frames", "x..y"]);
    assert_eq!(r.status.code(), Some(2), "clap rejects a malformed range");
}
