//! Frame rendering throughput: one OS1-64 scan (64 × 1024) of an urban scene from a vehicle.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use pi3det_data::Platform;
use pi3det_sim::{Layout, Sequence, SequenceSpec, SimConfig};

fn render(c: &mut Criterion) {
    let cfg = SimConfig::default();
    let seq = Sequence::generate(
        &cfg,
        SequenceSpec { platform: Platform::Vehicle, index: 0, frames: 20, seed: 1, layout: Some(Layout::Urban) },
    )
    .expect("sequence");
    let mut g = c.benchmark_group("sim");
    g.throughput(Throughput::Elements(cfg.sensor.rays_per_scan() as u64));
    let mut f = 0;
    g.bench_function("render_frame_os1_64x1024", |b| {
        b.iter(|| {
            f = (f + 1) % seq.len();
            seq.render(f)
        })
    });
    g.finish();
}

criterion_group!(benches, render);
criterion_main!(benches);
