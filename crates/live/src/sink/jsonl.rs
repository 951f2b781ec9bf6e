//! One JSON line per sweep, written as it is made: `pi3det eval`'s format plus `timestamp_s`
//! and `latency_ms` (which the evaluator ignores).

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use pi3det_data::Object;
use pi3det_eval::detections::JsonlFrame;

use super::{create, FrameLatency, Sink};
use crate::error::{LiveError, Result};
use crate::source::LiveFrame;

pub struct JsonlSink {
    path: PathBuf,
    out: BufWriter<std::fs::File>,
}

impl JsonlSink {
    pub fn create(path: &Path, overwrite: bool) -> Result<Self> {
        Ok(Self { out: BufWriter::new(create(path, overwrite)?), path: path.to_path_buf() })
    }
}

impl Sink for JsonlSink {
    fn describe(&self) -> String {
        self.path.display().to_string()
    }

    fn write(&mut self, frame: &LiveFrame, objects: &[Object], latency: &FrameLatency) -> Result<()> {
        let mut line = JsonlFrame::from_objects(frame.frame.info.id.clone(), objects);
        line.timestamp_s = frame.frame.info.timestamp_s;
        line.latency_ms = Some(
            [
                ("queue", latency.queue_ms),
                ("prep", latency.prep_ms),
                ("network", latency.network_ms),
                ("post", latency.post_ms),
                ("total", latency.total_ms),
            ]
            .into_iter()
            .map(|(k, v)| (k.to_string(), (v * 1000.0).round() / 1000.0))
            .collect(),
        );
        let io = |e| LiveError::io(&self.path, e);
        serde_json::to_writer(&mut self.out, &line).map_err(|e| LiveError::invalid(&self.path, e.to_string()))?;
        self.out.write_all(b"\n").map_err(io)?;
        // A line per sweep reaches the file at once: a reader tails it, a crash loses nothing.
        self.out.flush().map_err(|e| LiveError::io(&self.path, e))
    }

    fn finish(&mut self) -> Result<()> {
        self.out.flush().map_err(|e| LiveError::io(&self.path, e))
    }
}
