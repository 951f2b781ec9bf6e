//! Pi3DET-Net's pipeline end to end on a tiny simulated vehicle → drone task: every stage runs
//! (PA with RPJ, GTD and PFA; pseudo-labels through VPP; KA with one source and one target batch
//! per step), a run interrupted after PA and resumed ends with exactly the weights of an
//! uninterrupted run, and bad input is refused with a clear error before anything is written.

use std::path::Path;

use pi3det_adapt::pipeline::{self, AdaptConfig, AdaptEvent, AdaptOptions, Component, Stage};
use pi3det_data::Platform;
use pi3det_nn::checkpoint;
use pi3det_nn::data_loader::{open_split, Subset};
use pi3det_nn::testing::{tiny_detector, tiny_roi_head};
use pi3det_nn::DetectorConfig;
use pi3det_sim::{ExportOptions, PlatformPlan, SimConfig};
use tch::{Device, Tensor};

/// libtorch's generator is one per process: tests that train take turns.
static TORCH_RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn config() -> AdaptConfig {
    let base = AdaptConfig::default();
    let mut detector = DetectorConfig {
        name: "tiny_pi3det_net".into(),
        roi_head: Some(tiny_roi_head()),
        neck: base.detector.neck.clone(),
        pfa: Some(pi3det_nn::roi_heads::pfa::PfaConfig {
            latent_channels: 8,
            hidden_channels: 16,
            ..Default::default()
        }),
        // Wide enough for a drone's ground (seen from up to 20 m, little of it nearby).
        ..tiny_detector(25.6, 0.8)
    };
    detector.train.augment = base.detector.train.augment.clone();
    let mut cfg = AdaptConfig { name: "tiny".into(), detector, ..base };
    cfg.ka.epochs = 2;
    // An untrained PA model scores low: let its boxes through as pseudo-labels.
    cfg.pseudo_labels.positive_score = 0.05;
    cfg.pseudo_labels.ignore_score = 0.02;
    cfg
}

fn weights(path: &Path) -> Vec<(String, Tensor)> {
    let ck = checkpoint::load(path).unwrap();
    let mut v: Vec<(String, Tensor)> = ck.tensors.into_iter().filter(|(k, _)| k.starts_with("model.")).collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// `ka/final.safetensors` removed and the run resumed from its checkpoints: the new final weights.
fn rerun_final(cfg: &AdaptConfig, d: &Data, out: &Path) -> Vec<(String, Tensor)> {
    let path = out.join("ka/final.safetensors");
    std::fs::remove_file(&path).unwrap();
    let mut o = options(cfg, d, out);
    o.resume = true;
    pipeline::run(o, &mut |_| {}).unwrap();
    weights(&path)
}

fn assert_same(a: &[(String, Tensor)], b: &[(String, Tensor)], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: another number of tensors");
    for ((na, ta), (nb, tb)) in a.iter().zip(b) {
        assert_eq!(na, nb);
        assert!(ta.equal(tb), "{na} differs {what}");
    }
}

struct Data {
    _dir: tempfile::TempDir,
    root: std::path::PathBuf,
    source: Subset,
    target: Subset,
    val: Subset,
}

fn data() -> Data {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().to_path_buf();
    let plans = [
        PlatformPlan { platform: Platform::Vehicle, sequences: 2, frames: 3, val_sequences: 1 },
        PlatformPlan { platform: Platform::Drone, sequences: 2, frames: 3, val_sequences: 1 },
    ];
    let opts = ExportOptions {
        out: root.join("data"),
        seed: 3,
        overwrite: false,
        per_platform_folders: true,
        layout: None,
        stratify_layouts: false,
    };
    pi3det_sim::export(&SimConfig::default(), &plans, &opts, &mut |_, _| {}).unwrap();
    let open = |p: &str, s: &str| Subset::all(open_split(&root.join("data").join(p).join(s), Some(s)).unwrap());
    Data {
        source: open("vehicle", "train"),
        target: open("drone", "train"),
        val: open("drone", "val"),
        root,
        _dir: dir,
    }
}

fn options(cfg: &AdaptConfig, d: &Data, out: &Path) -> AdaptOptions {
    AdaptOptions {
        config: cfg.clone(),
        source: d.source.clone(),
        target: d.target.clone(),
        val: None,
        out_dir: out.to_path_buf(),
        device: Device::Cpu,
        pa_ckpt: None,
        resume: false,
        stop_after: Some(Stage::Ka),
        source_only: None,
        vpp_diagnostics: true,
    }
}

#[test]
fn stages_run_and_resume_across_pa_ka_reproduces_an_uninterrupted_run() {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    tch::set_num_threads(1);
    let d = data();
    assert!(d.source.len() >= 3 && d.target.len() >= 3);
    let cfg = config();
    assert_eq!(cfg.components(), vec![Component::Rpj, Component::Vpp, Component::Gtd, Component::Pfa]);

    // Uninterrupted, recording the steps and PA's loss terms.
    let a = d.root.join("a");
    let mut steps = Vec::new();
    let mut pa_terms: Vec<&'static str> = Vec::new();
    let report = pipeline::run(options(&cfg, &d, &a), &mut |e| match e {
        AdaptEvent::KaStep(s) => steps.push(s.clone()),
        AdaptEvent::Pa(pi3det_nn::train::Event::Step(s)) => pa_terms = s.terms.iter().map(|(n, _)| *n).collect(),
        _ => {}
    })
    .unwrap();
    for t in ["rot", "pfa_roi"] {
        assert!(pa_terms.contains(&t), "PA computes {t}: {pa_terms:?}");
    }
    // Every KA step trained on a source batch and a target batch.
    assert_eq!(steps.len(), cfg.ka.epochs * d.target.len(), "{:?}", report);
    // (A target frame whose pseudo-labels are all in the ignored band adds no background loss:
    // KA's coverage rule, crates/nn/src/losses/target_negatives.rs.)
    assert!(steps.iter().all(|s| s.source > 0.0 && s.target >= 0.0 && s.loss >= s.source + s.target - 1e-6));
    assert!(steps.iter().any(|s| s.target > 0.0), "the target batches train");
    assert!(report.vpp.unwrap().frames == d.target.len(), "{:?}", report.vpp);
    assert!(a.join("pseudo_labels.jsonl").is_file());
    let ck = checkpoint::load(&a.join("pa/final.safetensors")).unwrap();
    assert_eq!(ck.state.stage.as_deref(), Some("pa"));
    let ck = checkpoint::load(&a.join("ka/checkpoint_epoch_1.safetensors")).unwrap();
    assert_eq!(ck.state.stage.as_deref(), Some("ka"));

    // Stopped after PA, then resumed: same final weights.
    let b = d.root.join("b");
    let mut o = options(&cfg, &d, &b);
    o.stop_after = Some(Stage::Pa);
    pipeline::run(o, &mut |_| {}).unwrap();
    assert!(b.join("pa/final.safetensors").is_file() && !b.join("ka").exists());
    // Without resume the folder is refused.
    let err = pipeline::run(options(&cfg, &d, &b), &mut |_| {}).unwrap_err().to_string();
    assert!(err.contains("earlier adaptation run"), "{err}");
    let mut o = options(&cfg, &d, &b);
    o.resume = true;
    pipeline::run(o, &mut |_| {}).unwrap();
    for ((na, ta), (_, tb)) in
        weights(&a.join("pa/final.safetensors")).iter().zip(&weights(&b.join("pa/final.safetensors")))
    {
        assert!(ta.equal(tb), "PA: {na} differs between two identical runs");
    }
    let (la, lb) = (
        std::fs::read_to_string(a.join("pseudo_labels.jsonl")).unwrap(),
        std::fs::read_to_string(b.join("pseudo_labels.jsonl")).unwrap(),
    );
    assert_eq!(la, lb, "pseudo-labels differ");
    let wa = weights(&a.join("ka/final.safetensors"));
    assert_same(&wa, &weights(&b.join("ka/final.safetensors")), "after resuming across PA → KA");

    // Resumed from KA's epoch-1 checkpoint (the final one removed): same weights again.
    assert_same(&wa, &rerun_final(&cfg, &d, &b), "after resuming inside KA");

    // With a PA share (`ka.pa_weight`) the last epoch is kept as a checkpoint and `final` is the
    // blend of it with the PA weights, also when a run resumes after its last epoch.
    let mut shared = cfg.clone();
    shared.ka.pa_weight = 0.5;
    let c = d.root.join("c");
    // Run to the end with a validation split: the adapted model against the PA model through
    // VPP, with an interval over the split's sequences, in the report and its markdown.
    let mut o = options(&shared, &d, &c);
    o.val = Some(d.val.clone());
    o.stop_after = None;
    let report = pipeline::run(o, &mut |_| {}).unwrap();
    assert_eq!(report.val_sequences, 1);
    assert!(!report.adapted_vs_pa_vpp.is_empty());
    for r in &report.adapted_vs_pa_vpp {
        let (a, p) = (report.adapted.as_ref().unwrap(), report.source_only_vpp.as_ref().unwrap());
        let want = a.get(&r.class).unwrap().bev_r40 - p.get(&r.class).unwrap().bev_r40;
        assert!((r.bev.diff - want).abs() < 1e-9 || (r.bev.diff.is_nan() && want.is_nan()), "{r:?}");
    }
    let md = std::fs::read_to_string(c.join("adapt.md")).unwrap();
    assert!(md.contains("adapted − PA through VPP"), "{md}");
    let last = c.join(format!("ka/checkpoint_epoch_{}.safetensors", cfg.ka.epochs));
    let pa = weights(&c.join("pa/final.safetensors"));
    let blended = weights(&c.join("ka/final.safetensors"));
    for (((n, ka), (_, p)), (_, f)) in weights(&last).iter().zip(&pa).zip(&blended) {
        assert!(ka.equal(&wa.iter().find(|(m, _)| m == n).unwrap().1), "{n}: KA's last epoch as without the share");
        if f.is_floating_point() {
            let want = ka * 0.5 + p * 0.5;
            assert!((f - want).abs().max().double_value(&[]) < 1e-5, "{n} is not the blend");
        }
    }
    assert_same(&blended, &rerun_final(&shared, &d, &c), "when blending again after the last epoch");
}

#[test]
fn bad_input_is_refused_before_anything_is_written() {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    tch::set_num_threads(1);
    let d = data();
    let cfg = config();
    let run = |o: AdaptOptions| pipeline::run(o, &mut |_| {}).map(|_| ()).unwrap_err().to_string();

    // A target whose labels use other class names.
    let mut renamed = cfg.clone();
    renamed.detector.class_aliases.clear();
    renamed.detector.classes = vec!["car".into(), "pedestrian".into()];
    renamed.detector.train.augment.retain(|a| !matches!(a, pi3det_nn::augment::AugmentConfig::GtSampling(_)));
    if let Some(pi3det_nn::dense_heads::AnchorHeadConfig { anchors, .. }) = match &mut renamed.detector.head {
        pi3det_nn::config::HeadConfig::Anchor(a) => Some(a),
        _ => None,
    } {
        anchors[0].class = "car".into();
        anchors[1].class = "pedestrian".into();
    }
    let out = d.root.join("classes");
    let err = run(options(&renamed, &d, &out));
    assert!(err.contains("none of which") && err.contains("Car"), "{err}");
    assert!(!out.exists(), "nothing written");

    // A target split without frames.
    let mut o = options(&cfg, &d, &d.root.join("empty"));
    o.target = Subset { indices: Vec::new(), ..d.target.clone() };
    let err = run(o);
    assert!(err.contains("target split has no frames"), "{err}");

    // A PA checkpoint of another architecture.
    let other = cfg.without(&[Component::Gtd]);
    let out = d.root.join("other");
    let mut o = options(&other, &d, &out);
    o.stop_after = Some(Stage::Pa);
    pipeline::run(o, &mut |_| {}).unwrap();
    let mut o = options(&cfg, &d, &d.root.join("with_pa"));
    o.pa_ckpt = Some(out.join("pa/final.safetensors"));
    let err = run(o);
    assert!(err.contains("another architecture") && err.contains("neck"), "{err}");
    assert!(!d.root.join("with_pa").exists(), "nothing written");

    // `ka.frozen` naming no part of the detector: refused before PA, not after it.
    let mut typo = cfg.clone();
    typo.ka.frozen = vec!["backbone2d".into()];
    let out = d.root.join("typo");
    let err = run(options(&typo, &d, &out));
    assert!(err.contains("ka.frozen") && err.contains("backbone2d"), "{err}");
    assert!(!out.exists(), "nothing written");
}

/// Issue 47: a target where the PA model is sure of nothing. Its pseudo-labels hold no
/// positive, only boxes in the ignored band, so before the background rules every target anchor
/// and RoI was trained as background (the target loss KA then drives down is "nothing is here").
/// With the rules (the defaults) the target batches push nothing down, the adapted model still
/// finds what the PA model found through VPP (the guard's retention, which ships it), and the
/// report warns that the positives are too few and names both checkpoints.
#[test]
fn scarce_pseudo_labels_leave_what_the_pa_model_found() {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    tch::set_num_threads(1);
    let d = data();
    let mut cfg = config();
    // A PA model that knows its few frames (no augmentation, many passes); the target is those
    // frames, so what it finds there is worth keeping.
    cfg.detector.train.epochs = 40;
    cfg.detector.train.lr = 0.01;
    cfg.detector.train.augment.clear();
    // A tiny model's scores are all low: the band and the reported boxes start near zero, and
    // nothing reaches the positive score (nor may a lowered threshold: this is the case where
    // the target gives nothing to adapt on).
    cfg.detector.post.score_threshold = 0.002;
    cfg.pseudo_labels.positive_score = 0.95;
    cfg.pseudo_labels.ignore_score = 0.002;
    cfg.adaptive_thresholds.enabled = false;
    cfg.ka.epochs = 8;
    cfg.ka.lr = 0.003;
    cfg.guard.max_frames = 0;
    let pa_dir = d.root.join("pa_only");
    let mut o = options(&cfg, &d, &pa_dir);
    o.stop_after = Some(Stage::Pa);
    pipeline::run(o, &mut |_| {}).unwrap();
    let pa = pa_dir.join("pa/final.safetensors");
    let adapt = |cfg: &AdaptConfig, name: &str| {
        let mut o = options(cfg, &d, &d.root.join(name));
        o.target = d.source.clone();
        o.stop_after = None;
        o.pa_ckpt = Some(pa.clone());
        pipeline::run(o, &mut |_| {}).unwrap()
    };

    let on = adapt(&cfg, "rules_on");
    let round = &on.label_rounds[0];
    assert_eq!(round.positives.positives, 0, "{round:?}");
    assert!(round.thresholds.classes[0].boxes > 0, "the PA model found boxes (all in the band)");
    assert!(on.warnings.iter().any(|w| w.contains("positive pseudo-labels per target frame")), "{:?}", on.warnings);
    // Every target frame is covered by ignored boxes only: no background loss at all.
    assert_eq!(on.ka_epochs.len(), cfg.ka.epochs);
    assert!(on.ka_epochs.iter().all(|e| e.mean_target == 0.0 && e.mean_background_weight == 0.0), "{:?}", on.ka_epochs);
    let g = on.guard.as_ref().expect("the guard compared the models");
    assert_eq!(g.frames, d.source.len());
    assert!(g.pa_vpp.detections > 0 && g.adapted.detections > 0, "{g:?}");
    assert!(g.retained >= cfg.guard.min_retention, "no collapse: {g:?}");
    assert_eq!(g.ship, pi3det_adapt::guard::Ship::Adapted, "{g:?}");
    assert_eq!(g.pa_checkpoint, pa);
    assert!(g.pa_checkpoint.is_file() && g.adapted_checkpoint.is_file(), "both checkpoints are kept");
    let md = std::fs::read_to_string(d.root.join("rules_on/adapt.md")).unwrap();
    assert!(md.contains("ship adapted") && md.contains("Warnings:"), "{md}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.root.join("rules_on/adapt.json")).unwrap()).unwrap();
    assert_eq!(json["guard"]["ship"], "adapted");
    assert_eq!(json["label_rounds"][0]["positives"]["positives"], 0);

    // The PA model's scores as the background's teacher: loaded and run beside KA, and under
    // the same coverage rule (a frame of ignored boxes only teaches nothing either way).
    let mut teach = cfg.clone();
    teach.target_negatives.teacher_scores = true;
    let t = adapt(&teach, "teacher");
    assert!(t.ka_epochs.iter().all(|e| e.mean_target == 0.0), "{:?}", t.ka_epochs);
    assert!(t.guard.as_ref().is_some_and(|g| g.retained >= cfg.guard.min_retention), "{:?}", t.guard);

    // Without the rules the same labels make every target output background.
    let mut off = cfg.clone();
    off.target_negatives.enabled = false;
    let off = adapt(&off, "rules_off");
    assert!(
        off.ka_epochs.iter().all(|e| e.mean_target > 0.0 && e.mean_background_weight == 1.0),
        "{:?}",
        off.ka_epochs
    );
}
