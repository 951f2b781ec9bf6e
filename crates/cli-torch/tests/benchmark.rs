//! `pi3det bench suite` on a tiny simulated suite: every method runs to a result, the tables are
//! written, a second run skips finished cells and reruns only a changed one, the shards of a
//! suite cover it once and, merged, give the table of one unsharded run; a failing cell is
//! reported and does not stop the others; bad suites are refused naming what is wrong.

mod common;

use std::path::Path;

use common::{aps, args, write_suite, TORCH_RNG};
use pi3det_cli_torch::benchmark::stats;
use pi3det_cli_torch::benchmark::suite::Suite;
use pi3det_cli_torch::benchmark::table::Status;
use pi3det_cli_torch::benchmark::{self, BenchmarkArgs};

/// The folder of the tiny suite's quadruped validation split (simulated with its own seed).
fn quad_val_dir(out: &Path) -> std::path::PathBuf {
    std::fs::read_dir(out.join("data"))
        .unwrap()
        .flatten()
        .find(|e| e.file_name().to_string_lossy().starts_with("quad_val_") && e.path().is_dir())
        .unwrap()
        .path()
}

fn modified(out: &Path, cell: &str) -> std::time::SystemTime {
    std::fs::metadata(out.join("cells").join(cell).join("result.json")).unwrap().modified().unwrap()
}

#[test]
fn every_method_runs_resumes_and_shards_merge_to_one_run() {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let all = ["source_only", "target_only", "combined", "sn", "st3d", "st3d_pp", "redb", "ms3d_pp", "pi3det_net"];
    let suite = write_suite(dir.path(), &all, 1);
    let out = dir.path().join("a");
    let results = benchmark::run(&args(&suite, &out)).unwrap();
    assert_eq!(results.len(), all.len());
    for r in &results {
        assert_eq!(r.status, Status::Done, "{}: {:?}", r.id, r.error);
        let ap = r.ap.as_ref().unwrap();
        assert!(ap.frames > 0 && ap.get("Car").is_some(), "{}: {ap:?}", r.id);
    }
    // Self-training methods logged their pseudo-labels' quality against the target's ground truth.
    let st3d = results.iter().find(|r| r.id == "v2q/st3d/tiny").unwrap();
    assert!(
        !st3d.pseudo_labels.is_empty() && st3d.pseudo_labels[0]["quality"].as_array().is_some_and(|q| !q.is_empty())
    );
    // MS3D++ fused the boxes of two source models (the detector at two seeds, by default).
    let log = std::fs::read_to_string(out.join("cells/v2q__ms3dpp__tiny/log.txt")).unwrap();
    assert_eq!(log.matches("MS3D++ member:").count(), 2, "{log}");
    // Target-only: the source model's step budget, in levelled target frames.
    let log = std::fs::read_to_string(out.join("cells/v2q__target_only__tiny/log.txt")).unwrap();
    assert!(log.contains("for the source model's 3 steps") && log.contains("levelled to a 1.90 m"), "{log}");
    for f in ["benchmark.md", "benchmark.csv", "benchmark.json", "gap_closed.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let md = std::fs::read_to_string(out.join("benchmark.md")).unwrap();
    for label in ["Source Only", "ST3D++", "REDB", "MS3D++", "Pi3DET-Net", "Target Only †", "Combined †", "SN"] {
        assert!(md.contains(&format!("| {label} |")), "{label} in\n{md}");
    }

    // A second run skips every finished cell; changing one method reruns that cell only.
    let before: Vec<_> = ["v2q__source_only__tiny", "v2q__st3d__tiny"].iter().map(|c| modified(&out, c)).collect();
    benchmark::run(&args(&suite, &out)).unwrap();
    assert_eq!(modified(&out, "v2q__source_only__tiny"), before[0]);
    assert_eq!(modified(&out, "v2q__st3d__tiny"), before[1]);
    let suite2 = write_suite(dir.path(), &all, 2);
    let again = benchmark::run(&args(&suite2, &out)).unwrap();
    assert_eq!(modified(&out, "v2q__source_only__tiny"), before[0], "unchanged cells are skipped");
    assert_ne!(modified(&out, "v2q__st3d__tiny"), before[1], "the changed cell ran again");
    assert_eq!(again.len(), all.len());
    // ST3D over two epochs, refreshed every epoch: label rounds at epochs 0 and 1 (the memory merged).
    let st3d = again.iter().find(|r| r.id == "v2q/st3d/tiny").unwrap();
    let epochs: Vec<u64> = st3d.pseudo_labels.iter().map(|r| r["epoch"].as_u64().unwrap()).collect();
    assert_eq!(epochs, vec![0, 1]);

    // Shards: two machines, then a merge, give the unsharded table.
    let few = ["source_only", "st3d", "ms3d_pp"];
    let sub = tempfile::tempdir().unwrap();
    let suite = write_suite(sub.path(), &few, 1);
    let whole = benchmark::run(&args(&suite, &sub.path().join("whole"))).unwrap();
    let mut parts = Vec::new();
    for i in 1..=2 {
        let o = sub.path().join(format!("shard{i}"));
        let a = BenchmarkArgs { shard: Some(format!("{i}/2").parse().unwrap()), ..args(&suite, &o) };
        benchmark::run(&a).unwrap();
        parts.push(o);
    }
    let s = Suite::from_file(&suite).unwrap();
    let n: Vec<usize> = parts.iter().map(|p| benchmark::collect(&s, p).len()).collect();
    assert_eq!(n, vec![2, 1], "shard 1/2 takes cells 1 and 3, 2/2 cell 2");
    let merged = benchmark::run(&BenchmarkArgs { merge: parts, ..args(&suite, &sub.path().join("merged")) }).unwrap();
    assert_eq!(aps(&merged), aps(&whole));
}

#[test]
fn a_failing_cell_is_reported_and_the_others_run() {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let suite = write_suite(dir.path(), &["source_only", "target_only"], 1);
    // The target's validation split vanishes after the suite was checked: only cells that read it fail.
    let out = dir.path().join("out");
    let mut a = args(&suite, &out);
    a.only = vec!["v2q/source_only/*".into()];
    benchmark::run(&a).unwrap();
    let data = quad_val_dir(&out);
    std::fs::remove_file(data.join("quadruped/val/pi3det_infos_val.pkl")).unwrap();
    let results = benchmark::run(&BenchmarkArgs { force: true, ..args(&suite, &out) }).unwrap();
    assert!(results.iter().all(|r| r.status == Status::Failed), "{results:?}");
    let md = std::fs::read_to_string(out.join("benchmark.md")).unwrap();
    assert!(md.contains("## Failed cells") && md.contains("v2q/target_only/tiny"), "{md}");
    let log = std::fs::read_to_string(out.join("cells/v2q__target_only__tiny/log.txt")).unwrap();
    assert!(log.contains("FAILED"), "{log}");
}

#[test]
fn bad_suites_are_refused_naming_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read_to_string(write_suite(dir.path(), &["source_only", "pi3det_net"], 1)).unwrap();
    let path = dir.path().join("suite.toml");
    let check = |text: String, want: &str| {
        let e = format!("{:#}", Suite::from_toml_str(&text, &path).unwrap_err());
        assert!(e.contains(want), "want {want:?} in {e}");
    };
    check(good.replace("kind = \"source_only\"", "kind = \"st4d\""), "st4d");
    check(good.replace("target = \"quad\"", "target = \"drone\""), "unknown dataset \"drone\"");
    check(
        good.replace(
            "sim = { platform = \"vehicle\", sequences = 2, val_sequences = 1, frames = 3 }",
            "path = \"nowhere\"",
        ),
        "nowhere",
    );
    check(good.replace("config = \"det.toml\"", "config = \"missing.toml\""), "missing.toml");
    check(good.replace("pi3det_net = \"net.toml\"\n", ""), "pi3det_net");
    check(good.replace("platform = \"vehicle\"", "platform = \"boat\""), "boat");
    check(good.replace("[[methods]]\nkind = \"pi3det_net\"", "[[methods]]\nkind = \"source_only\""), "appears twice");
    assert!(Suite::from_toml_str(&good, &path).is_ok());

    // Rows that would differ by their post-processing too: refused unless asked, then flagged.
    let mut other = common::tiny_detector();
    other.post.tta = Some(Default::default());
    std::fs::write(dir.path().join("other.toml"), other.to_toml()).unwrap();
    let mixed = good.replace("config = \"det.toml\"", "config = \"other.toml\"");
    check(mixed.clone(), "post-processes otherwise");
    let flagged = Suite::from_toml_str(
        &mixed.replace("pi3det_net = \"net.toml\"", "pi3det_net = \"net.toml\"\nmixed_post = true"),
        &path,
    )
    .unwrap();
    assert!(flagged.detectors["tiny"].mixed_post);
    assert!(benchmark::table::markdown(&flagged, &[]).contains("post-process otherwise than Pi3DET-Net"));
    // MS3D++ fuses several detectors: one member alone is refused unless asked for.
    let one = format!("{good}[[methods]]\nkind = \"ms3d_pp\"\nensemble = [{{}}]\n");
    check(one.clone(), "at least two different members");
    assert!(Suite::from_toml_str(&format!("{one}allow_single_member = true\n"), &path).is_ok());
    check(
        format!("{good}[[methods]]\nkind = \"ms3d_pp\"\nensemble = [{{}}, {{ config = \"nope.toml\" }}]\n"),
        "nope.toml",
    );
    // Without `config` the baselines run the Pi3DET-Net detector less its components.
    let derived = Suite::from_toml_str(&good.replace("config = \"det.toml\"\n", ""), &path).unwrap();
    let d = &derived.detectors["tiny"];
    assert!(!d.mixed_post && d.config.neck.is_none() && d.config.pfa.is_none());
    assert_eq!(d.config.post, d.pi3det_net.as_ref().unwrap().detector.post);
}

#[test]
fn shipped_suites_parse() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/benchmark");
    let mini = Suite::from_file(&dir.join("mini.toml")).unwrap();
    assert_eq!(mini.cells().len(), 3 * 5);
    // One network and post-processing for every row; a fixed, stratified validation of ≥ 12
    // sequences per target; target-only as many steps as the source.
    assert!(mini.detectors.values().all(|d| !d.mixed_post));
    for t in &mini.tasks {
        let sim = mini.datasets[&t.target].sim.as_ref().unwrap();
        assert!(sim.val_sequences >= 12 && sim.val_seed.is_some(), "{}: {sim:?}", t.target);
    }
    assert!(mini.schedule.equal_steps);
    // Table 5: six component sets between source-only and target-only.
    let ablation = Suite::from_file(&dir.join("ablation.toml")).unwrap();
    let labels: Vec<String> = ablation.methods.iter().map(|m| m.label()).collect();
    assert_eq!(labels.len(), 8);
    assert_eq!(labels[1], "Pi3DET-Net (KA alone)");
    assert_eq!(labels[6], "Pi3DET-Net (RPJ + VPP + PFA + GTD)");
    // Each component measured against the nearest row without it: RPJ and VPP alone on KA alone,
    // RPJ on VPP (the row above has RPJ but not VPP), then PFA and GTD cumulatively.
    let steps: Vec<(String, usize, usize)> =
        stats::component_steps(&ablation.methods).into_iter().map(|s| (s.added, s.with, s.without)).collect();
    let want = [("RPJ", 2, 1), ("VPP", 3, 1), ("RPJ", 4, 3), ("PFA", 5, 4), ("GTD", 6, 5)];
    assert_eq!(steps, want.map(|(a, w, o)| (a.to_string(), w, o)));
    let paper = Suite::from_file(&dir.join("paper.toml")).unwrap();
    assert_eq!((paper.tasks.len(), paper.methods.len()), (8, 11));
    assert_eq!(paper.cells().len(), 88);
}

/// Two runs sharing an output folder never run one cell at once: the second leaves a cell whose
/// lock the first holds.
#[test]
fn a_cell_locked_by_another_run_is_left_to_it() {
    let dir = tempfile::tempdir().unwrap();
    let suite = write_suite(dir.path(), &["source_only"], 1);
    let out = dir.path().join("out");
    std::fs::create_dir_all(out.join("cells")).unwrap();
    let held = std::fs::File::create(out.join("cells/v2q__source_only__tiny.lock")).unwrap();
    held.lock().unwrap();
    let results = benchmark::run(&args(&suite, &out)).unwrap();
    assert!(results.is_empty(), "{results:?}");
    assert!(!out.join("cells/v2q__source_only__tiny").exists());
}

/// `--seeds`: one run per seed, the validation split identical across seeds (its own seed), and a
/// table of per-seed values, mean ± spread and each row's interval against source-only.
#[test]
fn seeds_run_paired_with_one_validation_split_and_intervals() {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let suite = write_suite(dir.path(), &["source_only", "target_only"], 1);
    let out = dir.path().join("out");
    let results = benchmark::run(&BenchmarkArgs { seeds: vec![1, 2], ..args(&suite, &out) }).unwrap();
    assert_eq!(results.len(), 4);
    let val_infos = |seed: u64| {
        let d = quad_val_dir(&out.join(format!("seed_{seed}")));
        std::fs::read(d.join("quadruped/val/pi3det_infos_val.pkl")).unwrap()
    };
    assert_eq!(val_infos(1), val_infos(2), "the validation split does not move with the seed");
    let md = std::fs::read_to_string(out.join("benchmark.md")).unwrap();
    assert!(md.contains("seeds [1, 2]") && md.contains("95 % interval"), "{md}");
    let row = md.lines().find(|l| l.starts_with("| Target Only |")).unwrap();
    assert!(row.matches(" / ").count() == 1 && row.contains(" ± ") && row.contains('['), "{row}");
}

/// An ablation row keeps only its components: its Pre-Adaptation and KA run without the others.
#[test]
fn an_ablation_row_runs_pi3det_net_with_its_components_only() {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let suite = write_suite(dir.path(), &["source_only"], 1);
    let text = std::fs::read_to_string(&suite).unwrap()
        + "[[methods]]\nkind = \"pi3det_net\"\ncomponents = [\"vpp\"]\n[[methods]]\nkind = \"pi3det_net\"\ncomponents = []\n";
    std::fs::write(&suite, &text).unwrap();
    let out = dir.path().join("out");
    let results = benchmark::run(&args(&suite, &out)).unwrap();
    let row = results.iter().find(|r| r.method == "Pi3DET-Net (VPP)").unwrap();
    assert_eq!(row.status, Status::Done, "{:?}", row.error);
    let log = std::fs::read_to_string(out.join("cells/v2q__pi3det_net_vpp__tiny/log.txt")).unwrap();
    assert!(log.contains("Pi3DET-Net components: VPP"), "{log}");
    // VPP alone leaves PA as source-only's training: the row reuses that model.
    assert!(
        log.contains("PA without RPJ, PFA and GTD: the source-only model") && !log.contains("training pa_"),
        "{log}"
    );
    // KA alone: the target through the suite's one height shift, as source-only sees it.
    let log = std::fs::read_to_string(out.join("cells/v2q__pi3det_net_ka_alone__tiny/log.txt")).unwrap();
    let shift = |l: &str| l.split("shift_z ").nth(1).map(|r| r.split(' ').next().unwrap().to_string());
    let suite_shift = log.lines().find(|l| l.contains("target frames: shift_z")).and_then(shift);
    let ka_shift = log.lines().find(|l| l.contains("target frames without VPP")).and_then(shift);
    assert!(suite_shift.is_some() && suite_shift == ka_shift, "{log}");
    // Components belong to Pi3DET-Net.
    let bad = text.replace("kind = \"source_only\"", "kind = \"source_only\"\ncomponents = []");
    let e = format!("{:#}", Suite::from_toml_str(&bad, &suite).unwrap_err());
    assert!(e.contains("are Pi3DET-Net's"), "{e}");
}
