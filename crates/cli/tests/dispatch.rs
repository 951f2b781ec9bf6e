//! `pi3det` without libtorch: the binary neither links nor loads it, its own commands (`--version`,
//! `eval`) work, and the detector commands are listed in its help and handed to `pi3det-torch`
//! with their arguments verbatim and its exit status (a stand-in executable shows what arrives; the
//! real one, when built beside `pi3det` as `cargo test --workspace` does, shows its help).

mod common;

use common::commands;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const PI3DET: &str = env!("CARGO_BIN_EXE_pi3det");

fn pi3det(args: &[&str]) -> Command {
    let mut c = Command::new(PI3DET);
    c.args(args).env_remove("PI3DET_TORCH");
    c
}

fn run(c: &mut Command) -> Output {
    c.output().expect("run pi3det")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn ok(out: &Output, what: &str) -> String {
    assert!(out.status.success(), "{what} failed:\n{}\n{}", text(&out.stdout), text(&out.stderr));
    text(&out.stdout)
}

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    assert!(p.exists(), "{} is missing (the test data beside the repository)", p.display());
    p
}

#[test]
fn version_and_eval_without_libtorch() {
    // The dynamic section names no libtorch library (readelf, where binutils is installed).
    if let Ok(out) = Command::new("readelf").args(["-d", PI3DET]).output() {
        let dynamic = text(&out.stdout);
        assert!(dynamic.contains("NEEDED"), "readelf -d printed no dynamic section:\n{dynamic}");
        assert!(!dynamic.contains("libtorch") && !dynamic.contains("libc10"), "{dynamic}");
    }
    // Nor does the dynamic loader load one (glibc's LD_DEBUG lists every library it loads).
    let out = run(pi3det(&["--version"]).env("LD_DEBUG", "libs"));
    let version = ok(&out, "--version");
    assert!(version.starts_with("pi3det "), "{version}");
    let loader = text(&out.stderr);
    if loader.contains("libc.so") {
        assert!(!loader.contains("libtorch") && !loader.contains("libc10"), "pi3det loaded libtorch:\n{loader}");
    }

    // `pi3det eval` on real frames, the detections being the ground truth itself: the same
    // numbers as the evaluator in this process.
    let gt = shared("pi3det_sample");
    let ds = pi3det_data::open(&gt).unwrap();
    let lines: Vec<String> = (0..ds.len())
        .map(|i| {
            let info = ds.info(i).unwrap();
            serde_json::to_string(&pi3det_eval::JsonlFrame::from_objects(info.id.clone(), &info.objects)).unwrap()
        })
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let det = tmp.path().join("gt.jsonl");
    std::fs::write(&det, lines.join("\n")).unwrap();
    let out = run(pi3det(&["eval", "--gt", gt.to_str().unwrap(), "--det", det.to_str().unwrap(), "--json"])
        .env("LD_DEBUG", "libs"));
    let report: pi3det_eval::EvalReport = serde_json::from_str(&ok(&out, "eval")).unwrap();
    let dets = pi3det_eval::Detections::read(&det).unwrap();
    let here = pi3det_eval::evaluate_dataset(ds.as_ref(), &dets, &report.options).unwrap();
    assert_eq!(report.overall, here.overall);
    let car = report.overall.classes.iter().find(|c| c.class == "Car").expect("Car");
    assert!(car.sets[0].d3.r40.iter().any(|&ap| ap > 0.0), "{car:?}");
    assert!(!text(&out.stderr).contains("libtorch"), "eval loaded libtorch");
}

#[test]
fn help_lists_the_detector_commands() {
    let help = ok(&run(&mut pi3det(&["--help"])), "--help");
    for c in ["info", "simulate", "eval", "stats", "train", "detect", "demo", "bench"] {
        assert!(help.lines().any(|l| l.trim_start().starts_with(c)), "{c} missing from\n{help}");
    }
    let bench = ok(&run(&mut pi3det(&["bench", "--help"])), "bench --help");
    assert!(bench.contains("sim") && bench.contains("nn"), "{bench}");
}

/// A stand-in for pi3det-torch that prints its arguments, one per line, and exits with 7.
fn fake_torch(dir: &Path) -> PathBuf {
    let p = dir.join("pi3det-torch");
    std::fs::write(&p, "#!/bin/sh\nfor a in \"$@\"; do echo \"[$a]\"; done\nexit 7\n").unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    p
}

#[test]
fn detector_commands_are_handed_over_verbatim() {
    let tmp = tempfile::tempdir().unwrap();
    let fake = fake_torch(tmp.path());
    let cases: &[&[&str]] = &[
        &["train", "--help"],
        &["--threads", "3", "train", "--config", "a b.toml", "--seed=-1", "--", "x"],
        &["detect", "--ckpt", "c.safetensors", "--eval"],
        &["demo"],
        &["bench", "nn", "--json", "--no-torch"],
        &["help", "train"],
        &["help", "bench", "nn"],
    ];
    for args in cases {
        let out = run(pi3det(args).env("PI3DET_TORCH", &fake));
        assert_eq!(out.status.code(), Some(7), "{args:?}: exit status not passed through; {}", text(&out.stderr));
        let got: Vec<String> = text(&out.stdout).lines().map(|l| l.trim_matches(['[', ']']).to_string()).collect();
        assert_eq!(got, args.iter().map(|a| a.to_string()).collect::<Vec<_>>(), "{args:?}");
    }
    // pi3det's own commands stay here.
    let out = run(pi3det(&["bench", "sim", "--help"]).env("PI3DET_TORCH", &fake));
    assert!(ok(&out, "bench sim --help").contains("Usage"));
}

#[test]
fn a_missing_pi3det_torch_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let out = run(pi3det(&["train", "--help"]).env("PI3DET_TORCH", tmp.path().join("nope")));
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("nope"), "{}", text(&out.stderr));
    // A pi3det with no pi3det-torch beside it or on PATH names the command that builds one.
    let lonely = tmp.path().join("pi3det");
    std::fs::copy(PI3DET, &lonely).unwrap();
    // A child forked by another test thread while the copy was open for writing holds that
    // descriptor until it execs, and executing the copy meanwhile fails with "text file busy".
    let out = (0..50)
        .find_map(|_| {
            match Command::new(&lonely).args(["train", "--help"]).env_remove("PI3DET_TORCH").env("PATH", "").output() {
                Err(e) if e.kind() == std::io::ErrorKind::ExecutableFileBusy => {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                    None
                }
                r => Some(r.unwrap()),
            }
        })
        .expect("the copied pi3det stayed busy");
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(err.contains("pi3det-torch") && err.contains("cargo build --release -p pi3det-cli-torch"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn train_help_reaches_pi3det_torch() {
    let real = Path::new(PI3DET).with_file_name("pi3det-torch");
    if !real.is_file() {
        eprintln!(
            "note: {} is not built (cargo test --workspace builds it); only the stand-in was tested",
            real.display()
        );
        return;
    }
    let help = ok(&run(&mut pi3det(&["train", "--help"])), "train --help");
    assert!(
        help.contains("Usage: pi3det train") && help.contains("--config") && help.contains("--max-val-frames"),
        "{help}"
    );
    let help = ok(&run(&mut pi3det(&["help", "demo"])), "help demo");
    assert!(help.contains("--seeds") && help.contains("--train-sequences"), "{help}");
    // Its errors and exit status come back as they are (clap: 2).
    let out = run(&mut pi3det(&["train", "--no-such-flag"]));
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(text(&out.stderr).contains("--no-such-flag"));
}

/// Every command `pi3det` hands over is one `pi3det-torch` has, and the other way round.
#[test]
fn pi3det_and_pi3det_torch_agree_on_the_detector_commands() {
    let tmp = tempfile::tempdir().unwrap();
    let fake = fake_torch(tmp.path());
    let mut words = Vec::new();
    for c in commands(&ok(&run(&mut pi3det(&["--help"])), "--help")) {
        if c == "bench" {
            for s in commands(&ok(&run(&mut pi3det(&["bench", "--help"])), "bench --help")) {
                words.push(vec![c.clone(), s]);
            }
        } else {
            words.push(vec![c]);
        }
    }
    let mut handed: Vec<String> = words
        .iter()
        .filter(|w| {
            let args: Vec<&str> = w.iter().map(String::as_str).chain(["--help"]).collect();
            run(pi3det(&args).env("PI3DET_TORCH", &fake)).status.code() == Some(7)
        })
        .map(|w| w.join(" "))
        .collect();
    handed.sort();
    assert!(handed.contains(&"train".to_string()) && handed.contains(&"bench live".to_string()), "{handed:?}");
    let real = Path::new(PI3DET).with_file_name("pi3det-torch");
    if !real.is_file() {
        eprintln!("note: {} is not built; only pi3det's side was listed: {handed:?}", real.display());
        return;
    }
    let torch = |args: &[&str]| ok(&run(Command::new(&real).args(args)), "pi3det-torch --help");
    let mut own = Vec::new();
    for c in commands(&torch(&["--help"])) {
        if c == "bench" {
            own.extend(commands(&torch(&["bench", "--help"])).into_iter().map(|s| format!("bench {s}")));
        } else {
            own.push(c);
        }
    }
    own.sort();
    assert_eq!(handed, own, "pi3det hands over / pi3det-torch has");
}
