//! Gradient sanity of the custom parts: the losses against finite differences, and the heads'
//! losses on assigned targets — gradients only where the assignment says, pointing the right
//! way, and a gradient step moving decoded boxes towards their ground truth.

use pi3det_geometry::{bev_iou, Box3d};
use pi3det_nn::box_coder::ResidualCoder;
use pi3det_nn::dense_heads::anchor_head::{AnchorBatchTargets, AnchorOutput};
use pi3det_nn::dense_heads::center_head::{CenterBatchTargets, CenterOutput};
use pi3det_nn::dense_heads::{AnchorHeadConfig, CenterHeadConfig};
use pi3det_nn::losses;
use pi3det_nn::target_assigner::center::{self, CenterMap, CenterTargetConfig};
use pi3det_nn::target_assigner::{axis_aligned, AnchorClassConfig, Anchors};
use tch::{nn, Device, Kind, Tensor};

fn finite_difference_check(f: impl Fn(&Tensor) -> Tensor, x0: &[f32], tol: f64) {
    let x = Tensor::from_slice(x0).to_kind(Kind::Double).set_requires_grad(true);
    f(&x).backward();
    let g: Vec<f64> = Vec::try_from(x.grad()).unwrap();
    let eps = 1e-6;
    for i in 0..x0.len() {
        let at = |d: f64| {
            let mut v: Vec<f64> = x0.iter().map(|&a| a as f64).collect();
            v[i] += d;
            f(&Tensor::from_slice(&v)).double_value(&[])
        };
        let num = (at(eps) - at(-eps)) / (2.0 * eps);
        assert!((num - g[i]).abs() < tol * (1.0 + num.abs()), "component {i}: numeric {num}, autograd {}", g[i]);
    }
}

#[test]
fn losses_match_finite_differences() {
    let t = Tensor::from_slice(&[1.0f64, 0.0, 0.0, 1.0, 0.0, 0.0]).view([3, 2]);
    let w = Tensor::from_slice(&[1.0f64, 0.5, 2.0]);
    finite_difference_check(
        |x| losses::sigmoid_focal_loss(&x.view([3, 2]), &t, &w, 0.25, 2.0),
        &[0.3, -1.2, 2.0, 0.1, -0.4, 1.5],
        1e-5,
    );
    let tg = Tensor::from_slice(&[0.1f64, -0.2, 3.0]).view([1, 3]);
    let cw = Tensor::from_slice(&[1.0f64, 2.0, 1.0]);
    let rw = Tensor::from_slice(&[0.5f64]);
    finite_difference_check(
        |x| {
            let (p, q) = losses::add_sin_difference(&x.view([1, 3]), &tg, 2);
            losses::weighted_smooth_l1(&p, &q, &cw, &rw, 1.0 / 9.0)
        },
        &[0.3, -0.21, 0.4],
        1e-5,
    );
    let hm = Tensor::from_slice(&[1.0f64, 0.6, 0.1, 0.0]).view([1, 4]);
    finite_difference_check(|x| losses::center_focal_loss(&x.view([1, 4]), &hm), &[0.5, -0.3, 0.2, -2.0], 1e-5);
}

fn anchor_classes() -> Vec<AnchorClassConfig> {
    AnchorHeadConfig::default().anchors
}

#[test]
fn anchor_loss_gradients_follow_the_assignment() {
    let classes = anchor_classes();
    let anchors =
        Anchors::generate(&[(0, classes[0].clone()), (1, classes[1].clone())], 16, 16, [0.8, 0.8], [-6.4, -6.4]);
    let gt = vec![Box3d::new(1.1, -0.7, 0.8, 4.4, 1.9, 1.6, 0.2), Box3d::new(-3.0, 2.9, 0.85, 0.7, 0.6, 1.7, 1.2)];
    let t = axis_aligned::assign(&anchors, &classes, &gt, &[0, 1], &[], &[]);
    let n = anchors.len() as i64;
    let cfg = AnchorHeadConfig::default();
    let vs = nn::VarStore::new(Device::Cpu);
    let map = CenterMap { h: 16, w: 16, cell: [0.8, 0.8], origin: [-6.4, -6.4] };
    let head = cfg.init(vs.root(), 8, 2, &map);
    // Random outputs we differentiate with respect to.
    tch::manual_seed(3);
    let cls = (Tensor::randn([1, n, 2], (Kind::Float, Device::Cpu)) * 0.5).set_requires_grad(true);
    let boxes = (Tensor::randn([1, n, 7], (Kind::Float, Device::Cpu)) * 0.1).set_requires_grad(true);
    let dir = Tensor::zeros([1, n, 2], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let p = t.pos_index.len() as i64;
    let targets = AnchorBatchTargets {
        labels: Tensor::from_slice(&t.labels).view([1, n]),
        pos_index: Tensor::from_slice(&t.pos_index),
        pos_codes: Tensor::from_slice(&t.pos_codes).view([p, 7]),
        pos_dir: Tensor::from_slice(&t.pos_dir),
        pos_weight: Tensor::full([p], 1.0 / p as f64, (Kind::Float, Device::Cpu)),
        near_index: Tensor::from_slice(&t.near_positive),
    };
    let out = AnchorOutput { cls: cls.shallow_clone(), boxes: boxes.shallow_clone(), dir: dir.shallow_clone() };
    let (total, _) = head.loss(&out, &targets);
    total.backward();
    let gc: Vec<f32> = Vec::try_from(cls.grad().view([-1])).unwrap();
    let gb: Vec<f32> = Vec::try_from(boxes.grad().view([-1])).unwrap();
    let gd: Vec<f32> = Vec::try_from(dir.grad().view([-1])).unwrap();
    let pos: std::collections::HashSet<usize> = t.pos_index.iter().map(|&k| k as usize).collect();
    assert!(!pos.is_empty());
    for (k, &label) in t.labels.iter().enumerate() {
        let (g0, g1) = (gc[2 * k], gc[2 * k + 1]);
        match label {
            -1 => assert!(g0 == 0.0 && g1 == 0.0, "ignored anchor {k} got a gradient"),
            0 => assert!(g0 > 0.0 && g1 > 0.0, "background anchor {k}: push both classes down"),
            l => {
                let (own, other) = if l == 1 { (g0, g1) } else { (g1, g0) };
                assert!(own < 0.0 && other > 0.0, "positive anchor {k}: raise its class, lower the other");
            }
        }
        let box_grad = gb[7 * k..7 * k + 7].iter().any(|&v| v != 0.0);
        let dir_grad = gd[2 * k..2 * k + 2].iter().any(|&v| v != 0.0);
        assert_eq!(box_grad, pos.contains(&k), "box gradient only at positives (anchor {k})");
        assert_eq!(dir_grad, pos.contains(&k), "direction gradient only at positives (anchor {k})");
    }
    // One gradient step on the box codes moves the decoded boxes towards their ground truth.
    let decoded_iou = |b: &Tensor| -> f64 {
        let codes: Vec<f32> = Vec::try_from(b.view([-1])).unwrap();
        t.pos_index
            .iter()
            .map(|&k| {
                let k = k as usize;
                let c: [f32; 7] = codes[7 * k..7 * k + 7].try_into().unwrap();
                let d = ResidualCoder::decode(&c, &anchors.boxes[k]);
                gt.iter().map(|g| bev_iou(g, &d)).fold(0.0, f64::max)
            })
            .sum::<f64>()
    };
    let before = decoded_iou(&boxes.detach());
    let g = boxes.grad();
    let scale = 0.01 / g.abs().max().double_value(&[]);
    let stepped = tch::no_grad(|| boxes.detach() - g * scale);
    let after = decoded_iou(&stepped);
    assert!(after > before, "IoU of decoded positives {before:.3} → {after:.3}");
}

#[test]
fn center_loss_gradients_follow_the_heatmap() {
    let map = CenterMap { h: 12, w: 12, cell: [0.8, 0.8], origin: [-4.8, -4.8] };
    let gt = vec![Box3d::new(0.5, -1.3, 0.8, 4.3, 1.9, 1.6, 0.7)];
    let t = center::assign(&CenterTargetConfig::default(), &map, 2, &gt, &[0], &[], &[]);
    let vs = nn::VarStore::new(Device::Cpu);
    let head = CenterHeadConfig::default().init(vs.root(), 8, 2, &pi3det_nn::BatchNorm::default(), &map);
    let hm = Tensor::full([1, 2, 12, 12], -2.0, (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let codes = Tensor::zeros([1, 8, 12, 12], (Kind::Float, Device::Cpu)).set_requires_grad(true);
    let targets = CenterBatchTargets {
        heatmap: Tensor::from_slice(&t.heatmap).view([1, 2, 12, 12]),
        index: Tensor::from_slice(&t.index),
        codes: Tensor::from_slice(&t.codes).view([1, 8]),
        mask: None,
    };
    let (total, _) = head.loss(&CenterOutput { heatmap: hm.shallow_clone(), codes: codes.shallow_clone() }, &targets);
    total.backward();
    let g: Vec<f32> = Vec::try_from(hm.grad().view([-1])).unwrap();
    let centre = t.index[0] as usize;
    assert!(g[centre] < 0.0, "raise the heatmap at the centre");
    let target: Vec<f32> = t.heatmap.clone();
    for (i, (&gi, &ti)) in g.iter().zip(&target).enumerate() {
        if i != centre {
            assert!(gi > 0.0, "lower the heatmap off the centre (cell {i}, target {ti})");
        }
    }
    // Cells near the centre (high Gaussian target) are pushed down less than far ones.
    assert!(g[centre + 1] < g[centre + 5]);
    let gc: Vec<f32> = Vec::try_from(codes.grad().permute([0, 2, 3, 1]).reshape([-1])).unwrap();
    for cell in 0..144 {
        let any = gc[8 * cell..8 * cell + 8].iter().any(|&v| v != 0.0);
        assert_eq!(any, cell == centre, "code gradient only at the box centre (cell {cell})");
    }
}
