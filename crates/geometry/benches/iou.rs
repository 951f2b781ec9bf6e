//! Rotated IoU matrices and NMS at the sizes a detector meets per frame.
//! Run: `cargo bench -p pi3det-geometry`.

use criterion::{criterion_group, criterion_main, Criterion};
use pi3det_geometry::{bev_iou_matrix, iou_3d_matrix, nms, Box3d, NmsConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Boxes spread over a 100 m × 100 m scene, car to pedestrian sized, so many pairs overlap
/// locally as in a real frame with many detections.
fn boxes(n: usize, seed: u64) -> Vec<Box3d> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            Box3d::new(
                rng.random_range(0.0..40.0),
                rng.random_range(-20.0..20.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.5..5.0),
                rng.random_range(0.5..2.5),
                rng.random_range(1.0..2.0),
                rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
            )
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let (a, b) = (boxes(500, 1), boxes(500, 2));
    c.bench_function("bev_iou_matrix 500x500", |bench| bench.iter(|| bev_iou_matrix(&a, &b)));
    c.bench_function("iou_3d_matrix 500x500", |bench| bench.iter(|| iou_3d_matrix(&a, &b)));
    let dets = boxes(4096, 3);
    let scores: Vec<f64> = (0..dets.len()).map(|i| ((i * 7919) % 1000) as f64 / 1000.0).collect();
    let cfg = NmsConfig { iou_threshold: 0.1, score_threshold: 0.0, pre_max_size: 4096, post_max_size: 500 };
    c.bench_function("nms 4096 boxes", |bench| bench.iter(|| nms(&dets, &scores, &cfg)));
}

criterion_group!(benches, bench);
criterion_main!(benches);
