//! Decoding speed: frames/s from `*data*.h5` to points (HDF5 row read + LZF + packets + XYZ).

use std::path::Path;
use std::time::Instant;

use pi3det_data::{DataError, Dataset};
use rayon::prelude::*;

use crate::dataset::{SequenceDataset, SequenceOptions};
use crate::synth::{write_sequence, SynthSpec};

#[derive(Debug, Clone)]
pub struct BenchReport {
    pub source: String,
    pub frames: usize,
    pub points_per_frame: f64,
    pub threads: usize,
    pub parallel_fps: f64,
    pub single_thread_ms: f64,
    /// Of the single-thread time: reading the sweep's row (HDF5 + LZF).
    pub read_ms: f64,
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "sequence decoding ({}): {} frames, {:.0} points per frame",
            self.source, self.frames, self.points_per_frame
        )?;
        writeln!(f, "  {} threads: {:.1} frames/s", self.threads, self.parallel_fps)?;
        write!(
            f,
            "  1 thread:  {:.2} ms per frame ({:.1} frames/s), of which {:.2} ms HDF5 row read + LZF",
            self.single_thread_ms,
            1000.0 / self.single_thread_ms,
            self.read_ms
        )
    }
}

/// Times `frames` frames of `path` (default: a synthetic OS1-64 1024x10 LEGACY sequence written
/// to a temporary folder and removed afterwards).
pub fn run(path: Option<&Path>, frames: usize) -> Result<BenchReport, DataError> {
    let frames = frames.max(1);
    let tmp;
    let (root, source) = match path {
        Some(p) => (p.to_path_buf(), p.display().to_string()),
        None => {
            tmp = TempDir::new()?;
            write_sequence(&tmp.0, &SynthSpec::os1_64("bench_os1_64", frames))?;
            (tmp.0.clone(), "synthetic OS1-64 1024x10 LEGACY, LZF".to_string())
        }
    };
    let ds = SequenceDataset::open(&root, SequenceOptions { truncate: true, ..Default::default() })?;
    let n = frames.min(ds.len());
    if n == 0 {
        return Err(DataError::invalid(&root, "no frames to time"));
    }
    ds.load(0)?; // warm-up: the XYZ table, file handles
    let t = Instant::now();
    let points: usize = (0..n).into_par_iter().map(|i| ds.load(i).map(|f| f.points.len())).sum::<Result<usize, _>>()?;
    let parallel_fps = n as f64 / t.elapsed().as_secs_f64();
    let t = Instant::now();
    for i in 0..n {
        ds.load(i)?;
    }
    let single_thread_ms = t.elapsed().as_secs_f64() * 1000.0 / n as f64;
    let t = Instant::now();
    for i in 0..n {
        let (seq, k) = ds.locate(i)?;
        seq.read_row(k)?;
    }
    let read_ms = t.elapsed().as_secs_f64() * 1000.0 / n as f64;
    Ok(BenchReport {
        source,
        frames: n,
        points_per_frame: points as f64 / n as f64,
        threads: rayon::current_num_threads(),
        parallel_fps,
        single_thread_ms,
        read_ms,
    })
}

/// A folder under the system temp dir, removed on drop.
struct TempDir(std::path::PathBuf);

impl TempDir {
    fn new() -> Result<Self, DataError> {
        let p = std::env::temp_dir().join(format!("pi3det-seq-bench-{}", std::process::id()));
        std::fs::create_dir_all(&p).map_err(|e| DataError::io(&p, e))?;
        Ok(Self(p))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
