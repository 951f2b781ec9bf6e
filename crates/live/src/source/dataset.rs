//! Frames of a dataset folder as a stream (to test the live path on data with ground truth).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use pi3det_data::Dataset;

use super::{pace, Flow, LiveFrame, Source, SourceReport};
use crate::error::Result;

pub struct DatasetSource {
    dataset: Arc<dyn Dataset>,
    indices: Vec<usize>,
    rate_hz: Option<f64>,
    name: String,
}

impl DatasetSource {
    /// Frames `indices` of `dataset`, `rate_hz` per second (live-like) or as fast as taken.
    pub fn new(dataset: Arc<dyn Dataset>, indices: Vec<usize>, rate_hz: Option<f64>, name: String) -> Self {
        Self { dataset, indices, rate_hz, name }
    }
}

impl Source for DatasetSource {
    fn describe(&self) -> String {
        format!("{} ({} frames)", self.name, self.indices.len())
    }

    fn is_live(&self) -> bool {
        self.rate_hz.is_some()
    }

    fn run(&mut self, emit: &mut dyn FnMut(LiveFrame) -> Flow, stop: &AtomicBool) -> Result<SourceReport> {
        let mut report = SourceReport::default();
        let start = Instant::now();
        for (k, &i) in self.indices.iter().enumerate() {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            pace(start, k as u64, self.rate_hz);
            let frame = self.dataset.load(i)?;
            let stamp_ns = frame.info.timestamp_s.map_or(0, |t| (t * 1e9).max(0.0) as u64);
            report.sweeps += 1;
            if emit(LiveFrame { frame, stamp_ns, arrived: Instant::now() }) == Flow::Stop {
                break;
            }
        }
        Ok(report)
    }
}
