//! Reading frames: KITTI velodyne scans (≈120k points) with labels and calib, and the Pi3DET
//! info pickle. Run: `cargo bench -p pi3det-data` (needs ../shared/data).

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use pi3det_data::open;

fn shared(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel)
}

fn bench(c: &mut Criterion) {
    let kitti = open(&shared("kitti/training")).expect("../shared/data/kitti/training");
    c.bench_function("kitti load frame (points+labels+calib)", |b| b.iter(|| kitti.load(1).unwrap()));
    c.bench_function("kitti info only (labels+calib)", |b| b.iter(|| kitti.info(1).unwrap()));
    c.bench_function("pi3det open (info pickle, 6 frames)", |b| b.iter(|| open(&shared("pi3det_sample")).unwrap()));
    let nus = shared("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl");
    c.bench_function("nuscenes open (mmdet3d info)", |b| b.iter(|| open(&nus).unwrap()));
}

criterion_group!(benches, bench);
criterion_main!(benches);
