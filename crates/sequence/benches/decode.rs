//! `cargo bench -p pi3det-sequence`: one OS1-64 1024x10 sweep from LZF HDF5 to points.

use criterion::{criterion_group, criterion_main, Criterion};
use pi3det_data::Dataset;
use pi3det_sequence::synth::{write_sequence, SynthSpec};
use pi3det_sequence::{SequenceDataset, SequenceOptions};

fn decode(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path(), &SynthSpec::os1_64("bench", 4)).unwrap();
    let ds = SequenceDataset::open(dir.path(), SequenceOptions::default()).unwrap();
    let mut i = 0;
    c.bench_function("load one OS1-64 1024x10 sweep (LZF HDF5 -> points)", |b| {
        b.iter(|| {
            i = (i + 1) % ds.len();
            ds.load(i).unwrap().points.len()
        })
    });
}

criterion_group!(benches, decode);
criterion_main!(benches);
