//! Box fusion against scipy: random clusters fused here and by the reference in
//! `kbf_reference.py` (MS3D++'s steps over `scipy.stats.gaussian_kde`) in the project's venv
//! (`scripts/setup-python`). Skips with a message where that venv has no scipy.

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use pi3det_autolabel::fusion::{fuse_cluster, FusionConfig, Member};
use pi3det_geometry::Box3d;
use rand::{Rng, SeedableRng};

fn python() -> Option<PathBuf> {
    let py = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let ok = Command::new(&py).args(["-c", "import scipy, numpy"]).status().is_ok_and(|s| s.success());
    ok.then_some(py)
}

fn clusters(seed: u64) -> Vec<Vec<Member>> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..200)
        .map(|c| {
            let n = rng.random_range(3..12);
            let (cx, cy) = (rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0));
            let flat = c % 5 == 0; // equal z: the x/y + z branch
            let same_size = c % 7 == 0; // equal sizes: the size densities are singular
            (0..n)
                .map(|source| {
                    let j = |rng: &mut rand_chacha::ChaCha8Rng, s: f64| rng.random_range(-s..s);
                    let box3d = Box3d {
                        x: cx + j(&mut rng, 0.6),
                        y: cy + j(&mut rng, 0.6),
                        z: if flat { -0.9 } else { -0.9 + j(&mut rng, 0.2) },
                        dx: if same_size { 4.0 } else { 4.0 + j(&mut rng, 0.5) },
                        dy: if same_size { 1.8 } else { 1.8 + j(&mut rng, 0.2) },
                        dz: 1.6 + j(&mut rng, 0.1),
                        heading: 0.3 + j(&mut rng, 0.3),
                    };
                    let score: f64 = rng.random_range(0.2..1.0);
                    let weight = score * if source % 3 == 0 { 0.5 } else { 1.0 };
                    Member { box3d, score, weight, source }
                })
                .collect()
        })
        .collect()
}

#[test]
fn fused_boxes_equal_the_scipy_reference() {
    let Some(py) = python() else {
        eprintln!("skipped: .venv/bin/python with scipy not found (run scripts/setup-python)");
        return;
    };
    let cfg = FusionConfig::default();
    let cl = clusters(7);
    let input: Vec<serde_json::Value> = cl
        .iter()
        .map(|m| {
            serde_json::json!({
                "boxes": m.iter().map(|m| m.box3d.to_array()).collect::<Vec<_>>(),
                "scores": m.iter().map(|m| m.score).collect::<Vec<_>>(),
                "weights": m.iter().map(|m| m.weight).collect::<Vec<_>>(),
            })
        })
        .collect();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/kbf_reference.py");
    let mut child = Command::new(py).arg(script).stdin(Stdio::piped()).stdout(Stdio::piped()).spawn().unwrap();
    child.stdin.take().unwrap().write_all(serde_json::to_string(&input).unwrap().as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let reference: Vec<Vec<Option<f64>>> = serde_json::from_slice(&out.stdout).unwrap();
    let mut worst = 0.0f64;
    for (k, (members, r)) in cl.iter().zip(&reference).enumerate() {
        let f = fuse_cluster(members, &cfg).unwrap();
        let ours = f.box3d.to_array().into_iter().chain([f.score]);
        for (i, (a, b)) in ours.zip(r).enumerate() {
            // scipy failed to fit the heading only where we fall back as well; compare the rest.
            let Some(b) = b else { continue };
            let err = (a - b).abs();
            worst = worst.max(err);
            assert!(err < 1e-9, "cluster {k} field {i}: ours {a}, scipy {b}");
        }
    }
    eprintln!("200 clusters, largest difference {worst:.2e}");
}
