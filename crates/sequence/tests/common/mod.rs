//! Shared by the integration tests: the venv's Python with h5py + ouster-sdk, and the fixtures.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `<repo>/.venv/bin/python` when it imports h5py and the Ouster SDK (`scripts/setup-ouster`
/// installs them); `None`, with the reason printed, otherwise.
pub fn python() -> Option<PathBuf> {
    let py = repo_root().join(".venv/bin/python");
    if !py.exists() {
        eprintln!("SKIP: {} missing; run scripts/setup-ouster for the Ouster SDK peer check", py.display());
        return None;
    }
    let ok = Command::new(&py)
        .args(["-c", "import h5py, numpy, ouster.sdk.core"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        eprintln!("SKIP: {} lacks h5py / ouster-sdk; run scripts/setup-ouster", py.display());
        return None;
    }
    Some(py)
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

fn run(py: &Path, script: &str, args: &[&Path], extra: &[&str]) {
    let out = Command::new(py).arg(fixture(script)).args(args).args(extra).output().expect("run python");
    assert!(out.status.success(), "{script} failed: {}", String::from_utf8_lossy(&out.stderr));
}

/// Writes the synthetic release (or one broken sequence) under `out`.
pub fn make_sequences(py: &Path, out: &Path, bad: Option<&str>) {
    match bad {
        Some(kind) => run(py, "make_sequence.py", &[out], &["--bad", kind]),
        None => run(py, "make_sequence.py", &[out], &[]),
    }
}

/// One point as the SDK decoded it.
#[derive(Debug, Clone, Copy)]
pub struct OraclePoint {
    pub xyz: [f64; 3],
    pub reflectivity: f64,
    pub timestamp_ns: u64,
    pub beam: u32,
}

/// Runs the SDK oracle on a data file: the points of each sweep.
pub fn oracle(py: &Path, data_h5: &Path, scratch: &Path) -> Vec<Vec<OraclePoint>> {
    let out = scratch.join(format!("{}.oracle", data_h5.file_name().unwrap().to_string_lossy()));
    run(py, "oracle_xyz.py", &[data_h5, &out], &[]);
    let b = std::fs::read(&out).unwrap();
    let f64_at = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let mut sweeps = Vec::new();
    let mut o = 0;
    while o < b.len() {
        let n = u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize;
        o += 4;
        let mut pts = Vec::with_capacity(n);
        for _ in 0..n {
            pts.push(OraclePoint {
                xyz: [f64_at(o), f64_at(o + 8), f64_at(o + 16)],
                reflectivity: f64_at(o + 24),
                timestamp_ns: u64::from_le_bytes(b[o + 32..o + 40].try_into().unwrap()),
                beam: u32::from_le_bytes(b[o + 40..o + 44].try_into().unwrap()),
            });
            o += 44;
        }
        sweeps.push(pts);
    }
    sweeps
}
