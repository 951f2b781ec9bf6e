//! `pi3det view` and `pi3det annotate` from the command line: the page is written once and not
//! replaced unasked; bad input and a non-loopback address are refused with a message.

use std::path::{Path, PathBuf};
use std::process::Command;

const PI3DET: &str = env!("CARGO_BIN_EXE_pi3det");

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "{} is missing (the test data beside the repository)", p.display());
    p
}

fn pi3det(args: &[&str]) -> (bool, String) {
    let out = Command::new(PI3DET).args(args).output().expect("run pi3det");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn view_writes_a_page_once() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene.html");
    let (data, o) = (shared("kitti/training"), out.to_str().unwrap().to_string());
    let d = data.to_str().unwrap();
    let (ok, err) =
        pi3det(&["view", d, "--frames", "0..2", "--max-points", "5000", "--color", "intensity", "--out", &o]);
    assert!(ok, "{err}");
    let html = std::fs::read_to_string(&out).unwrap();
    assert!(html.contains("\"n\":5000") && html.contains("\"id\":\"000001\""));
    let (ok, err) = pi3det(&["view", d, "--out", &o]);
    assert!(!ok && err.contains("scene.html") && err.contains("--overwrite"), "{err}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), html, "not replaced");
    let (ok, err) = pi3det(&["view", d, "--frames", "0..1", "--max-points", "10", "--out", &o, "--overwrite"]);
    assert!(ok, "{err}");
    let (ok, err) = pi3det(&["view", d, "--frames", "3..99", "--out", &o, "--overwrite"]);
    assert!(!ok && err.contains("outside the data's 6 frames"), "{err}");
}

#[test]
fn annotate_refuses_a_non_loopback_address() {
    let d = shared("pi3det_sample");
    let (ok, err) = pi3det(&["annotate", d.to_str().unwrap(), "--listen", "0.0.0.0:0"]);
    assert!(!ok && err.contains("--allow-remote"), "{err}");
    let (ok, err) = pi3det(&["annotate", d.to_str().unwrap(), "--label-set", "a/b"]);
    assert!(!ok && err.contains("--label-set"), "{err}");
}
