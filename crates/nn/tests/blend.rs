//! `Checkpoint::blend_into`: a weight-space blend of two checkpoints of one network (KA's
//! `pa_weight`) moves every floating-point variable, batch-norm statistics included, the given
//! share of the way, copies integer buffers, and refuses a checkpoint of another network.

use pi3det_nn::checkpoint::{self, TrainState};
use pi3det_nn::testing::tiny_detector;
use pi3det_nn::Detector;
use tch::{Device, Kind};

#[test]
fn blend_moves_every_variable_the_given_share() {
    tch::manual_seed(0);
    let cfg = tiny_detector(8.0, 0.5);
    let dir = tempfile::tempdir().unwrap();
    let a_path = dir.path().join("a.safetensors");
    let a = Detector::new(&cfg, Device::Cpu).unwrap();
    checkpoint::save(&a_path, &a, None, &TrainState::default()).unwrap();
    // A second network of the same shape with other values everywhere (weights and buffers).
    let mut b = Detector::new(&cfg, Device::Cpu).unwrap();
    tch::no_grad(|| {
        for (_, mut v) in b.vs.variables() {
            if v.is_floating_point() {
                let r = v.rand_like() + 0.5;
                v.copy_(&r);
            }
        }
    });
    let before: Vec<(String, tch::Tensor)> = b.vs.variables().into_iter().map(|(n, t)| (n, t.copy())).collect();
    let ck = checkpoint::load(&a_path).unwrap();
    ck.blend_into(&mut b, &a_path, 0.25).unwrap();
    let after = b.vs.variables();
    let mut floats = 0;
    for (name, old) in &before {
        let from_a = &ck.tensors[&format!("model.{name}")];
        let got = &after[name];
        if old.is_floating_point() {
            let want = old * 0.75 + from_a * 0.25;
            let err = (got - want).abs().max().double_value(&[]);
            assert!(err < 1e-6, "{name}: off by {err}");
            floats += 1;
        } else {
            assert!(got.equal(from_a), "{name}: an integer buffer is copied");
        }
    }
    assert!(floats > 10 && before.iter().any(|(n, _)| n.ends_with("running_mean")), "weights and statistics");
    // Weight 1 is a plain load.
    ck.blend_into(&mut b, &a_path, 1.0).unwrap();
    for (name, t) in b.vs.variables() {
        assert!(t.to_kind(Kind::Double).equal(&ck.tensors[&format!("model.{name}")].to_kind(Kind::Double)), "{name}");
    }
    // Another network is refused, naming the file.
    let mut other = tiny_detector(8.0, 0.5);
    other.backbone.num_filters = vec![16, 32];
    let mut c = Detector::new(&other, Device::Cpu).unwrap();
    let e = ck.blend_into(&mut c, &a_path, 0.5).unwrap_err().to_string();
    assert!(e.contains("a.safetensors") && e.contains("shape"), "{e}");
}
