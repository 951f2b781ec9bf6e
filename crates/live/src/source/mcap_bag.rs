//! ROS 2 bags in MCAP (the ROS 2 default storage): `sensor_msgs/msg/PointCloud2` messages of
//! one topic, CDR-encoded, read lazily from a memory map, in log-time order as stored.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use pi3det_data::{Frame, FrameInfo};

use super::pointcloud2::PointCloud2;
use super::{pace, Flow, LiveFrame, Source, SourceReport};
use crate::error::{LiveError, Result};

pub const POINTCLOUD2: &str = "sensor_msgs/msg/PointCloud2";

pub struct McapSource {
    path: PathBuf,
    map: memmap2::Mmap,
    topic: String,
    rate_hz: Option<f64>,
}

fn mcap_error(path: &Path, e: impl std::fmt::Display) -> LiveError {
    LiveError::invalid(path, format!("not a readable MCAP file: {e}"))
}

/// `(topic, schema name, message encoding)` of every channel in the file's summary, or of every
/// message when the file has no summary (an unfinished recording).
pub fn channels(path: &Path, map: &[u8]) -> Result<Vec<(String, String, String)>> {
    let mut out: Vec<(String, String, String)> = Vec::new();
    let describe = |c: &mcap::Channel| {
        (c.topic.clone(), c.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default(), c.message_encoding.clone())
    };
    match mcap::Summary::read(map).map_err(|e| mcap_error(path, e))? {
        Some(summary) => out.extend(summary.channels.values().map(|c| describe(c))),
        None => {
            for m in mcap::MessageStream::new(map).map_err(|e| mcap_error(path, e))? {
                let m = m.map_err(|e| mcap_error(path, e))?;
                let d = describe(&m.channel);
                if !out.contains(&d) {
                    out.push(d);
                }
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Writes `clouds` as a ROS 2 bag (MCAP, CDR) on `topic`, stamped with their own times: test
/// data and replays for `pi3det run`.
pub fn write_bag(path: &Path, topic: &str, clouds: &[PointCloud2]) -> Result<()> {
    let err = |e: mcap::McapError| LiveError::invalid(path, format!("MCAP: {e}"));
    let file = std::fs::File::create(path).map_err(|e| LiveError::io(path, e))?;
    let mut w = mcap::Writer::new(std::io::BufWriter::new(file)).map_err(err)?;
    let schema = w.add_schema(POINTCLOUD2, "ros2msg", b"").map_err(err)?;
    let channel_id = w.add_channel(schema, topic, "cdr", &Default::default()).map_err(err)?;
    for (k, m) in clouds.iter().enumerate() {
        let h = mcap::records::MessageHeader {
            channel_id,
            sequence: k as u32,
            log_time: m.stamp_ns,
            publish_time: m.stamp_ns,
        };
        w.write_to_known_channel(&h, &m.encode()).map_err(err)?;
    }
    w.finish().map_err(err)?;
    Ok(())
}

impl McapSource {
    /// Opens `path` and checks the topic: it must exist and carry `PointCloud2` in CDR. Without
    /// `topic`, the file's only `PointCloud2` topic is taken.
    pub fn open(path: &Path, topic: Option<&str>, rate_hz: Option<f64>) -> Result<Self> {
        let file = std::fs::File::open(path).map_err(|e| LiveError::io(path, e))?;
        // SAFETY: the file is opened read-only; a bag rewritten while we read it could change
        // under the map, as with any reader of a file another process writes.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| LiveError::io(path, e))?;
        let chans = channels(path, &map)?;
        let list = || chans.iter().map(|(t, s, _)| format!("{t} ({s})")).collect::<Vec<_>>().join(", ");
        let topic = match topic {
            Some(t) => {
                let Some((_, schema, enc)) = chans.iter().find(|(name, _, _)| name == t) else {
                    return Err(LiveError::invalid(path, format!("no topic '{t}' (topics: {})", list())));
                };
                if schema != POINTCLOUD2 || enc != "cdr" {
                    return Err(LiveError::invalid(
                        path,
                        format!("topic '{t}' carries {schema} ({enc}), not {POINTCLOUD2} (cdr)"),
                    ));
                }
                t.to_string()
            }
            None => {
                let clouds: Vec<&String> =
                    chans.iter().filter(|(_, s, e)| s == POINTCLOUD2 && e == "cdr").map(|(t, _, _)| t).collect();
                match clouds.as_slice() {
                    [one] => one.to_string(),
                    [] => return Err(LiveError::invalid(path, format!("no {POINTCLOUD2} topic (topics: {})", list()))),
                    many => {
                        let names: Vec<&str> = many.iter().map(|s| s.as_str()).collect();
                        return Err(LiveError::invalid(
                            path,
                            format!("several {POINTCLOUD2} topics ({}): choose one with ?topic=", names.join(", ")),
                        ));
                    }
                }
            }
        };
        Ok(Self { path: path.to_path_buf(), map, topic, rate_hz })
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }
}

impl Source for McapSource {
    fn describe(&self) -> String {
        format!("mcap://{}?topic={}", self.path.display(), self.topic)
    }

    fn is_live(&self) -> bool {
        self.rate_hz.is_some()
    }

    fn run(&mut self, emit: &mut dyn FnMut(LiveFrame) -> Flow, stop: &AtomicBool) -> Result<SourceReport> {
        let mut report = SourceReport::default();
        let start = Instant::now();
        let stream = mcap::MessageStream::new(&self.map).map_err(|e| mcap_error(&self.path, e))?;
        for m in stream {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            let m = m.map_err(|e| mcap_error(&self.path, e))?;
            if m.channel.topic != self.topic {
                continue;
            }
            let k = report.sweeps;
            let where_ = || format!("topic {} message {k} (log time {} ns)", self.topic, m.log_time);
            let cloud = PointCloud2::decode(&m.data)
                .and_then(|c| c.to_points().map(|p| (c, p)))
                .map_err(|e| LiveError::invalid(&self.path, format!("{}: {e}", where_())))?;
            let (msg, (points, dropped)) = cloud;
            report.add("non_finite_points", dropped as u64);
            pace(start, k, self.rate_hz);
            let mut info = FrameInfo::new(format!("{k:06}"), self.path.clone());
            info.sequence = Some(self.topic.clone());
            info.timestamp_s = Some(msg.stamp_ns as f64 * 1e-9);
            info.point_channels = points.channels().to_vec();
            report.sweeps += 1;
            let frame = LiveFrame { frame: Frame { info, points }, stamp_ns: msg.stamp_ns, arrived: Instant::now() };
            if emit(frame) == Flow::Stop {
                break;
            }
        }
        Ok(report)
    }
}
