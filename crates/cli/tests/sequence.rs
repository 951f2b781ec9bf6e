//! `pi3det info` / `convert` / `stats` on the full sequence release (a synthetic one written in
//! pure Rust): the sequences are read directly, and their conversion is read by everything else.

use std::process::{Command, Output};

use pi3det_sequence::synth::{write_sequence, SynthSpec};

fn pi3det(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pi3det")).args(args).output().expect("run pi3det")
}

fn ok(out: Output, what: &str) -> String {
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{what} failed: {}{text}", String::from_utf8_lossy(&out.stderr));
    text
}

#[test]
fn info_convert_and_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let processed = dir.path().join("processed");
    write_sequence(&processed.join("Spot/indoor_day"), &SynthSpec::os1_64("spot_indoor_x", 2)).unwrap();
    let p = processed.to_str().unwrap();
    let info = ok(pi3det(&["info", p]), "info on sequences");
    assert!(info.contains("| platform quadruped | 2 |") && info.contains("sequence spot_indoor_x"), "{info}");

    let out = dir.path().join("layout");
    let o = out.to_str().unwrap();
    let conv = ok(pi3det(&["convert", p, "--to", "pi3det-layout", "--out", o]), "convert");
    assert!(conv.starts_with("2 frames"), "{conv}");
    let again = pi3det(&["convert", p, "--to", "pi3det-layout", "--out", o]);
    assert!(!again.status.success() && String::from_utf8_lossy(&again.stderr).contains("already exists"));
    ok(pi3det(&["convert", p, "--to", "pi3det-layout", "--out", o, "--overwrite"]), "convert --overwrite");

    let back = ok(pi3det(&["info", o]), "info on the converted layout");
    let rows = |t: &str| {
        t.lines()
            .filter(|l| l.starts_with("| platform") || l.starts_with("| all"))
            .map(String::from)
            .collect::<Vec<_>>()
    };
    assert_eq!(rows(&info), rows(&back));
    ok(pi3det(&["stats", o, "--out", dir.path().join("report").to_str().unwrap()]), "stats on the converted layout");

    let missing = pi3det(&["info", dir.path().join("nothing").to_str().unwrap()]);
    assert!(!missing.status.success());
}

/// The release's padded rows (the default of the synthetic writer) and exact-size rows of the
/// same packets convert to byte-identical layouts.
#[test]
fn padded_and_unpadded_sequences_convert_alike() {
    let dir = tempfile::tempdir().unwrap();
    let mut converted = Vec::new();
    for (name, pad) in [("padded", 1), ("exact", 0)] {
        let processed = dir.path().join(name).join("processed");
        let spec = SynthSpec { columns: 512, row_pad_bytes: pad, ..SynthSpec::os1_64("car_urban_day_x", 2) };
        write_sequence(&processed.join("Car/urban_day"), &spec).unwrap();
        let info = ok(pi3det(&["info", processed.to_str().unwrap()]), "info");
        assert!(info.contains("| platform vehicle | 2 |"), "{info}");
        let out = dir.path().join(name).join("layout");
        ok(
            pi3det(&["convert", processed.to_str().unwrap(), "--to", "pi3det-layout", "--out", out.to_str().unwrap()]),
            "convert",
        );
        converted.push(out);
    }
    let files = |root: &std::path::Path| {
        let mut v: Vec<_> = walk(root).into_iter().map(|p| p.strip_prefix(root).unwrap().to_path_buf()).collect();
        v.sort();
        v
    };
    let (a, b) = (files(&converted[0]), files(&converted[1]));
    assert_eq!(a, b);
    assert!(a.iter().any(|p| p.extension().is_some_and(|e| e == "bin")), "{a:?}");
    for p in &a {
        if p.extension().is_some_and(|e| e == "bin") {
            assert_eq!(
                std::fs::read(converted[0].join(p)).unwrap(),
                std::fs::read(converted[1].join(p)).unwrap(),
                "{p:?}"
            );
        }
    }
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}
