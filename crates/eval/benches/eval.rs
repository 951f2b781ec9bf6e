//! `cargo bench -p pi3det-eval`: the evaluation of a KITTI-val-sized synthetic split (3,769
//! frames, ~15 GT and 30 detections per frame, Car + Pedestrian) and of the 2,000-frame
//! 30k / 30k case.

#[path = "../examples/common/synthetic.rs"]
mod synthetic;

use criterion::{criterion_group, criterion_main, Criterion};
use pi3det_eval::{evaluate, EvalOptions};

fn bench(c: &mut Criterion) {
    let opts = EvalOptions { classes: vec!["Car".into(), "Pedestrian".into()], ..EvalOptions::default() };
    let mut g = c.benchmark_group("evaluate");
    g.sample_size(10);
    for (name, frames, gt, det) in [("kitti_val_3769x15x30", 3769, 15, 30), ("issue_2000x15x15", 2000, 15, 15)] {
        let s = synthetic::split(7, frames, gt, det);
        g.bench_function(name, |b| b.iter(|| evaluate(&s.gt, &s.dets, &opts).expect("evaluation")));
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
