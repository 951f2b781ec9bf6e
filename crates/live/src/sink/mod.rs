//! Where detections go, frame by frame as they are made.
//!
//! Addresses (`pi3det run --sink …`, several allowed):
//! - `jsonl://FILE` or a bare `*.jsonl` path: one JSON line per sweep, the format `pi3det eval`
//!   reads, plus `timestamp_s` and `latency_ms` ([`jsonl`]);
//! - `mcap://FILE[?points=false]` or a bare `*.mcap` path: Foxglove `SceneUpdate` boxes on
//!   `/pi3det/detections` and the sweep as a Foxglove `PointCloud` on `/pi3det/points`
//!   ([`mcap_out`]); open it in Foxglove.
//!
//! A sink never replaces an existing file unless asked (`overwrite`).

pub mod jsonl;
pub mod mcap_out;

use std::path::PathBuf;

use pi3det_data::Object;

use crate::error::{LiveError, Result};
use crate::source::{refuse_unknown, split_uri, LiveFrame};

/// Where one frame's time went (ms): waiting in the queue, point preparation, network,
/// decoding + NMS, and from the sweep's arrival to its detections (`total`).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct FrameLatency {
    pub queue_ms: f64,
    pub prep_ms: f64,
    pub network_ms: f64,
    pub post_ms: f64,
    pub total_ms: f64,
}

pub trait Sink: Send {
    fn describe(&self) -> String;
    /// Writes one sweep's detections (boxes in the sweep's LiDAR frame).
    fn write(&mut self, frame: &LiveFrame, objects: &[Object], latency: &FrameLatency) -> Result<()>;
    /// Completes the output (indexes, flushes).
    fn finish(&mut self) -> Result<()>;
}

#[derive(Debug, Clone, PartialEq)]
pub enum SinkSpec {
    Jsonl(PathBuf),
    Mcap { path: PathBuf, points: bool },
}

impl SinkSpec {
    pub fn path(&self) -> &PathBuf {
        match self {
            Self::Jsonl(p) | Self::Mcap { path: p, .. } => p,
        }
    }
}

impl std::str::FromStr for SinkSpec {
    type Err = LiveError;

    fn from_str(uri: &str) -> Result<Self> {
        let (scheme, body, mut params) = split_uri(uri)?;
        let spec = match scheme {
            "jsonl" => Self::Jsonl(body.into()),
            "mcap" => {
                let points = match params.remove("points").as_deref() {
                    None | Some("true") => true,
                    Some("false") => false,
                    Some(v) => return Err(LiveError::uri(uri, format!("points={v}: expected true or false"))),
                };
                Self::Mcap { path: body.into(), points }
            }
            "" if body.ends_with(".jsonl") => Self::Jsonl(body.into()),
            "" if body.ends_with(".mcap") => Self::Mcap { path: body.into(), points: true },
            "" => return Err(LiveError::uri(uri, "a sink is jsonl://FILE, mcap://FILE, or a *.jsonl / *.mcap path")),
            other => return Err(LiveError::uri(uri, format!("unknown sink '{other}://' (jsonl, mcap)"))),
        };
        refuse_unknown(uri, &params, &["points"])?;
        if spec.path().as_os_str().is_empty() {
            return Err(LiveError::uri(uri, "no file name"));
        }
        Ok(spec)
    }
}

/// Creates `path` for writing, refusing an existing file unless `overwrite`; the parent folder
/// is created.
pub(crate) fn create(path: &std::path::Path, overwrite: bool) -> Result<std::fs::File> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| LiveError::io(dir, e))?;
    }
    let mut o = std::fs::OpenOptions::new();
    o.write(true);
    if overwrite {
        o.create(true).truncate(true);
    } else {
        o.create_new(true);
    }
    o.open(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::AlreadyExists {
            LiveError::invalid(path, "exists; pass --overwrite to replace it")
        } else {
            LiveError::io(path, e)
        }
    })
}

pub fn open_sink(spec: &SinkSpec, overwrite: bool) -> Result<Box<dyn Sink>> {
    Ok(match spec {
        SinkSpec::Jsonl(p) => Box::new(jsonl::JsonlSink::create(p, overwrite)?),
        SinkSpec::Mcap { path, points } => Box::new(mcap_out::McapSink::create(path, *points, overwrite)?),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sink_addresses() {
        assert_eq!("out/d.jsonl".parse::<SinkSpec>().unwrap(), SinkSpec::Jsonl("out/d.jsonl".into()));
        assert_eq!(
            "mcap://r.mcap?points=false".parse::<SinkSpec>().unwrap(),
            SinkSpec::Mcap { path: "r.mcap".into(), points: false }
        );
        for (uri, needle) in
            [("out/d.txt", "a sink is"), ("mcap://r.mcap?points=2", "true or false"), ("jsonl://", "no file")]
        {
            let e = uri.parse::<SinkSpec>().unwrap_err().to_string();
            assert!(e.contains(needle), "{uri}: {e}");
        }
    }
}
