//! TorchScript export: the traced modules compute what the Rust network computes, for the
//! first stage on a pillar count other than the traced one, and end to end the same detections
//! (single- and two-stage configs).

use std::path::Path;

use pi3det_data::{Frame, FrameInfo, PointCloud};
use pi3det_nn::data_loader::prepare_frame;
use pi3det_nn::export::{export, TorchScriptModel};
use pi3det_nn::{Detector, DetectorConfig};

fn frame(seed: u64, n: usize) -> Frame {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut r = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s % 10_000) as f32 / 10_000.0
    };
    // Ground plus a few box-shaped clusters, so that the heads see structure.
    let mut pts = Vec::new();
    for _ in 0..n {
        pts.push([r() * 60.0, r() * 60.0 - 30.0, -1.7 + 0.05 * r(), r()]);
    }
    for c in 0..6 {
        let (cx, cy) = (8.0 + 7.0 * c as f32, -12.0 + 5.0 * c as f32);
        for _ in 0..400 {
            pts.push([cx + 4.0 * r() - 2.0, cy + 1.8 * r() - 0.9, -1.7 + 1.5 * r(), r()]);
        }
    }
    Frame { info: FrameInfo::new(format!("{seed:06}"), Default::default()), points: PointCloud::from_xyzi(&pts) }
}

fn config(name: &str) -> DetectorConfig {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs").join(name);
    let mut cfg = DetectorConfig::from_file(&p).unwrap();
    // Untrained weights: let proposals and boxes through so the comparison has something to compare.
    cfg.post.score_threshold = 0.0;
    cfg
}

fn max_diff(a: &tch::Tensor, b: &tch::Tensor) -> f64 {
    assert_eq!(a.size(), b.size());
    (a - b).abs().max().double_value(&[])
}

fn check(cfg_name: &str) {
    tch::manual_seed(0);
    let cfg = config(cfg_name);
    let mut det = Detector::new(&cfg, tch::Device::Cpu).unwrap();
    let prep = det.prep.clone();
    let inputs = |f: &Frame| {
        let p = prepare_frame(&prep, &[], f, false, 0).unwrap();
        prep.collate_inputs(&[&p.pillars])
    };
    let x0 = inputs(&frame(1, 3000));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.pt");
    let files = export(&mut det, &x0, &out).unwrap();
    assert_eq!(files.roi.is_some(), cfg.roi_head.is_some());
    let ts = TorchScriptModel::load(&out, tch::Device::Cpu, |_| {}).unwrap();
    let _g = tch::no_grad_guard();
    // Another frame, another pillar count than the traced one.
    for f in [frame(2, 5000), frame(3, 800)] {
        let x = inputs(&f);
        assert_ne!(x.features.size()[0], x0.features.size()[0]);
        let native = det.forward_t(&x, false).unwrap();
        let traced = ts.forward(&x).unwrap();
        if native.roi.is_some() {
            let d = max_diff(&native.bev, &traced.bev);
            assert!(d < 1e-4, "{cfg_name}: BEV maps differ by {d}");
        }
        if let Some(r1) = &native.roi {
            // Natively, padding the RoIs to the traced count changes nothing for the real rows.
            let n = r1.out.rois.size()[1];
            let pad = tch::Tensor::zeros([1, 100 - n, 7], (tch::Kind::Float, tch::Device::Cpu));
            let padded = tch::Tensor::cat(&[&r1.out.rois, &pad], 1);
            let t = det.roi_tensors(&native.bev, &padded).unwrap().unwrap();
            let d = max_diff(&r1.out.iou_logits, &t[1].narrow(1, 0, n));
            assert!(d < 1e-5, "{cfg_name}: natively, padding changes RoI scores by {d}");
        }
        if let (Some(r1), Some(r2)) = (&native.roi, &traced.roi) {
            // Same proposals: padded rows aside, the RoI outputs agree.
            let n = r1.out.iou_logits.size()[1];
            for (what, u, v) in [
                ("rois", &r1.out.rois, &r2.out.rois),
                ("iou_logits", &r1.out.iou_logits, &r2.out.iou_logits),
                ("box_codes", &r1.out.box_codes, &r2.out.box_codes),
                ("features", &r1.out.features, &r2.out.features),
            ] {
                let d = max_diff(u, &v.narrow(1, 0, n));
                assert!(d < 1e-4, "{cfg_name}: RoI {what} differ by {d}");
            }
        }
        let a = det.post_process(&native, 1).unwrap();
        let b = ts.det.post_process(&traced, 1).unwrap();
        assert!(!a[0].is_empty(), "{cfg_name}: nothing detected, nothing compared");
        assert_eq!(a[0].len(), b[0].len(), "{cfg_name}: detection counts");
        for (p, q) in a[0].iter().zip(&b[0]) {
            assert_eq!(p.class, q.class);
            assert!((p.score - q.score).abs() < 1e-4, "{cfg_name}: {p:?} vs {q:?}");
            let (pa, qa) = (p.box3d.to_array(), q.box3d.to_array());
            for k in 0..7 {
                assert!((pa[k] - qa[k]).abs() < 1e-3, "{cfg_name}: {p:?} vs {q:?}");
            }
        }
    }
}

#[test]
fn single_stage_export_matches() {
    check("pointpillars_cpu.toml");
}

#[test]
fn two_stage_export_matches() {
    check("pointpillars_rcnn_cpu.toml");
}

#[test]
fn center_head_exports_match() {
    check("centerpoint_cpu.toml");
    check("centerpoint_rcnn_cpu.toml");
}
