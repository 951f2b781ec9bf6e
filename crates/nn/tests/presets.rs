//! The shipped presets build, and the CPU ones run a frame end to end (pillarize → network →
//! decode → NMS) with the right shapes; a voxel detector's checkpoint round trips and its
//! TorchScript export is refused with the reason.

use std::path::Path;

use pi3det_nn::augment::Sample;
use pi3det_nn::config::HeadConfig;
use pi3det_nn::{Detector, DetectorConfig};
use tch::Device;

fn preset(name: &str) -> DetectorConfig {
    DetectorConfig::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs").join(name)).unwrap()
}

fn frame() -> Sample {
    // A ground plane and a box-shaped cluster of points.
    let mut points = Vec::new();
    for i in 0..200 {
        for j in 0..50 {
            points.push([i as f32 * 0.3 - 30.0, j as f32 * 0.5 - 12.0, 0.0, 0.2]);
        }
    }
    for k in 0..300 {
        let t = k as f32 / 300.0;
        points.push([10.0 + 4.0 * t, 5.0 + (k % 3) as f32 * 0.9, 0.2 + 1.4 * t, 0.6]);
    }
    Sample { points, ..Default::default() }
}

#[test]
fn presets_build_and_run() {
    tch::set_num_threads(1);
    let paper = Detector::new(&preset("pointpillars_paper.toml"), Device::Cpu).unwrap();
    let HeadConfig::Anchor(head) = &paper.cfg().head else { panic!("the paper preset has an anchor head") };
    let anchors = head.assigner(&paper.prep.map).anchors;
    // Two Car sizes (sedan/van, bus) and one Pedestrian size, each at 0° and 90°.
    assert_eq!((anchors.h, anchors.w, anchors.per_location), (472, 472, 6));
    assert!(paper.num_parameters() > 4_000_000, "OpenPCDet's PointPillars has 4.8 M parameters");
    for name in [
        "pointpillars_cpu.toml",
        "centerpoint_cpu.toml",
        "second_cpu.toml",
        "second_iou_cpu.toml",
        "voxel_rcnn_cpu.toml",
    ] {
        let cfg = preset(name);
        let det = Detector::new(&cfg, Device::Cpu).unwrap();
        let s = frame();
        let p = det.prep.pillarizer().unwrap().run(&s.points, cfg.pillars.max_pillars_test);
        assert!(p.len() > 100);
        let dets = det.predict(&det.prep.collate_inputs(&[&p])).unwrap();
        assert_eq!(dets.len(), 1);
        assert!(dets[0].len() <= cfg.post.nms_post_max, "{name}");
        assert!(dets[0].iter().all(|d| d.score >= cfg.post.score_threshold && d.box3d.dx > 0.0), "{name}");
        // A frame without a single point in range is not an error.
        let empty = det.prep.pillarizer().unwrap().run(&[[500.0, 0.0, 0.0, 0.0]], cfg.pillars.max_pillars_test);
        assert!(empty.is_empty());
        let dets = det.predict(&det.prep.collate_inputs(&[&empty, &p])).unwrap();
        assert_eq!(dets.len(), 2);
    }
}

/// SECOND-IoU after a few training-mode passes (batch-norm statistics moved, weights perturbed):
/// saved and loaded, it predicts exactly what it predicted before.
#[test]
fn voxel_detector_checkpoint_round_trips() {
    tch::set_num_threads(1);
    tch::manual_seed(3);
    let cfg = preset("second_iou_cpu.toml");
    let mut det = Detector::new(&cfg, Device::Cpu).unwrap();
    assert!(det.has_backbone_3d());
    let s = frame();
    let p = det.prep.pillarizer().unwrap().run(&s.points, cfg.pillars.max_pillars_test);
    assert!(p.len() > 1000, "{} voxels", p.len());
    let x = det.prep.collate_inputs(&[&p]);
    {
        let _g = tch::no_grad_guard();
        for (_, v) in det.vs.variables() {
            let _ = v.shallow_clone().g_add_(&(v.randn_like() * 0.01));
        }
        for _ in 0..2 {
            let _ = det.bev_features(&x, true).unwrap();
        }
    }
    let before = det.predict(&x).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("second.safetensors");
    pi3det_nn::checkpoint::save(&path, &det, None, &Default::default()).unwrap();
    let (back, _) = pi3det_nn::checkpoint::load_detector(&path, Device::Cpu).unwrap();
    assert_eq!(back.cfg(), det.cfg());
    let after = back.predict(&x).unwrap();
    assert_eq!(format!("{before:?}"), format!("{after:?}"));
    // The network's outputs themselves, not only the (few) detections of a random model.
    let _g = tch::no_grad_guard();
    for (a, b) in det.dense_tensors(&x).unwrap().iter().zip(back.dense_tensors(&x).unwrap()) {
        assert!(a.numel() > 0 && a.equal(&b));
    }
    let err = pi3det_nn::export::export(&mut det, &x, &dir.path().join("m.pt")).err().unwrap().to_string();
    assert!(err.contains("rulebooks"), "{err}");
}

/// Mixed precision on the Pi3DET-Net preset's network (the one that infers in bf16): the same
/// weights give the f32 BEV map to within bf16's resolution, handed to the heads in f32.
#[test]
fn bf16_inference_matches_f32() {
    use pi3det_nn::precision::Precision;
    use pi3det_nn::preprocess::Preprocessor;
    tch::set_num_threads(1);
    tch::manual_seed(0);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/pi3det_net_cpu.toml");
    // The preset's `[detector]` table (the adaptation's own tables belong to pi3det-adapt).
    let preset: toml::Table = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let mut cfg = DetectorConfig::from_toml_str(&toml::to_string(&preset["detector"]).unwrap()).unwrap();
    cfg.precision = Precision::F32;
    let mut det = Detector::new(&cfg, Device::Cpu).unwrap();
    let p = det.prep.pillarizer().unwrap().run(&frame().points, cfg.pillars.max_pillars_test);
    let x = det.prep.collate_inputs(&[&p]);
    let bev32 = det.forward_t(&x, false).unwrap().bev;
    cfg.precision = Precision::Bf16;
    det.prep = std::sync::Arc::new(Preprocessor::new(&cfg).unwrap());
    let bev16 = det.forward_t(&x, false).unwrap().bev;
    assert_eq!(bev16.kind(), tch::Kind::Float);
    let err = (&bev16 - &bev32).abs().max().double_value(&[]);
    let scale = bev32.abs().max().double_value(&[]);
    assert!(scale > 0.0 && err < 0.05 * scale, "bf16 error {err} against max |bev| {scale}");
    assert_eq!(det.predict(&x).unwrap().len(), 1);
}
