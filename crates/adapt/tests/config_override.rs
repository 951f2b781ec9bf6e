//! `--set KEY=VALUE` overrides on an adaptation config (`pi3det adapt --set`): they reach the
//! adaptation's tables and the `[detector]` inside it, and a bad one names the file and the key.

use pi3det_adapt::pipeline::AdaptConfig;
use pi3det_nn::config_override::ConfigOverride;
use pi3det_nn::roi_heads::pfa::KlEstimator;
use pi3det_nn::DetectorConfig;

const PRESET: &str = include_str!("../../../configs/pi3det_net_cpu.toml");

fn set(s: &str) -> ConfigOverride {
    s.parse().unwrap()
}

fn preset_file() -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("net.toml");
    std::fs::write(&path, PRESET).unwrap();
    (dir, path)
}

#[test]
fn overrides_reach_the_adaptation_and_detector_configs() {
    let (_dir, path) = preset_file();
    let plain = AdaptConfig::from_file(&path).unwrap();
    let o = [
        set("pseudo_labels.positive_score=0.3"),
        set("detector.pfa.kl_weight=0"),
        set("detector.pfa.kl_estimator=mixture"),
        set("detector.head.anchors.0.matched_threshold=0.55"),
    ];
    let cfg = AdaptConfig::from_file_with(&path, &o).unwrap();
    assert_eq!(cfg.pseudo_labels.positive_score, 0.3);
    let pfa = cfg.detector.pfa.as_ref().unwrap();
    assert_eq!((pfa.kl_weight, pfa.kl_estimator), (0.0, KlEstimator::Mixture));
    // Nothing else moved: the same overrides by hand give the same config.
    let mut want = plain;
    want.pseudo_labels.positive_score = 0.3;
    let p = want.detector.pfa.as_mut().unwrap();
    p.kl_weight = 0.0;
    p.kl_estimator = KlEstimator::Mixture;
    let h = |c: &AdaptConfig| toml::to_string(&c.detector.head).unwrap();
    assert_eq!(h(&cfg), h(&want).replacen("matched_threshold = 0.6", "matched_threshold = 0.55", 1));
    want.detector.head = cfg.detector.head.clone();
    assert_eq!(cfg, want);

    let dir = tempfile::tempdir().unwrap();
    let det = dir.path().join("det.toml");
    std::fs::write(&det, "").unwrap();
    let d = DetectorConfig::from_file_with(&det, &[set("train.lr=0.002"), set("train.epochs=4")]).unwrap();
    assert_eq!((d.train.lr, d.train.epochs), (0.002, 4));
}

#[test]
fn a_misspelt_key_or_a_bad_value_names_the_file_and_the_override() {
    let (_dir, path) = preset_file();
    let before = std::fs::read_to_string(&path).unwrap();
    let e = AdaptConfig::from_file_with(&path, &[set("detector.pfa.kl_wieght=0")]).unwrap_err().to_string();
    assert!(e.contains("net.toml") && e.contains("kl_wieght") && e.contains("--set"), "{e}");
    let e = AdaptConfig::from_file_with(&path, &[set("ka.lr=fast")]).unwrap_err().to_string();
    assert!(e.contains("net.toml") && e.contains("ka.lr"), "{e}");
    // Parses, but validation refuses it (TOML reads `nan` as a float).
    let e = AdaptConfig::from_file_with(&path, &[set("detector.pfa.kl_weight=nan")]).unwrap_err().to_string();
    assert!(e.contains("net.toml") && e.contains("pfa"), "{e}");
    let e = AdaptConfig::from_file_with(&path, &[set("pseudo_labels.positive_score=1.5")]).unwrap_err().to_string();
    assert!(e.contains("net.toml") && e.contains("positive_score"), "{e}");
    // The new KA knobs: a misspelt term, a NaN weight, and a teacher on a head without the rule.
    let e = AdaptConfig::from_file_with(&path, &[set("ka.target_loss_weights.lco=0")]).unwrap_err().to_string();
    assert!(e.contains("net.toml") && e.contains("lco"), "{e}");
    let e = AdaptConfig::from_file_with(&path, &[set("ka.target_loss_weights.loc=nan")]).unwrap_err().to_string();
    assert!(e.contains("target_loss_weights"), "{e}");
    AdaptConfig::from_file_with(&path, &[set("target_negatives.teacher_scores=true")]).unwrap();
    let mut center = AdaptConfig::from_file_with(&path, &[set("target_negatives.teacher_scores=true")]).unwrap();
    center.detector.head = pi3det_nn::config::HeadConfig::Center(Default::default());
    let e = center.validate().unwrap_err().to_string();
    assert!(e.contains("teacher_scores") && e.contains("anchor head"), "{e}");
    // The target's own shift is for runs without VPP: with it, or not finite, refused.
    let e = AdaptConfig::from_file_with(&path, &[set("target_shift_z=-12.5")]).unwrap_err().to_string();
    assert!(e.contains("target_shift_z") && e.contains("VPP"), "{e}");
    let mut no_vpp = AdaptConfig::from_file(&path).unwrap().without(&[pi3det_adapt::pipeline::Component::Vpp]);
    no_vpp.target_shift_z = Some(-12.5);
    no_vpp.validate().unwrap();
    no_vpp.target_shift_z = Some(f64::NAN);
    assert!(no_vpp.validate().unwrap_err().to_string().contains("finite"));
    assert_eq!(std::fs::read_to_string(&path).unwrap(), before, "the file is never written");
}
