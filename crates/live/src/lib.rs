//! Running a detector on a robot: sensor data in as it arrives, detections out as they are made.
//!
//! - [`source`]: live Ouster lidar packets over UDP assembled into sweeps (the sequence reader's
//!   decoder), ROS 2 bags (MCAP, `sensor_msgs/msg/PointCloud2` in CDR), dataset folders at a rate.
//! - [`sink`]: JSON lines (what `pi3det eval` reads, with timestamps and latency) and MCAP files
//!   with Foxglove `SceneUpdate` boxes and the point cloud.
//! - [`queue`]: the bounded queue between decoding and inference that drops the oldest sweep
//!   when inference falls behind; [`latency`]: fixed-memory latency percentiles.
//! - [`replay`]: a loopback packet replayer with loss, reordering, duplicates, garbage, a
//!   frame-id wrap and a sensor restart, for tests and the soak benchmark.
//!
//! The inference loop itself (`pi3det run`) lives in crates/cli-torch, which links libtorch.

pub mod error;
pub mod latency;
pub mod queue;
pub mod replay;
pub mod sink;
pub mod source;

pub use error::{LiveError, Result};
pub use latency::LatencyHistogram;
pub use queue::DropOldestQueue;
pub use sink::{open_sink, Sink, SinkSpec};
pub use source::{open_source, Flow, LiveFrame, Source, SourceReport, SourceSpec};
