//! Detections as an MCAP file Foxglove opens: per sweep a `foxglove.SceneUpdate` on
//! `/pi3det/detections` (one cube and one label per box, coloured by class, replacing the
//! previous sweep's) and, unless turned off, the sweep as a `foxglove.PointCloud` on
//! `/pi3det/points` (x, y, z, intensity float32). Both in the `lidar` frame, stamped with the
//! sweep's time; protobuf with the schemas of the `foxglove` crate.

use std::io::BufWriter;
use std::path::{Path, PathBuf};

use foxglove::messages::{
    packed_element_field::NumericType, Color, CubePrimitive, PackedElementField, PointCloud, Pose, Quaternion,
    SceneEntity, SceneUpdate, TextPrimitive, Timestamp, Vector3,
};
use foxglove::Encode;
use pi3det_data::Object;

use super::{create, FrameLatency, Sink};
use crate::error::{LiveError, Result};
use crate::source::LiveFrame;

pub const DETECTIONS_TOPIC: &str = "/pi3det/detections";
pub const POINTS_TOPIC: &str = "/pi3det/points";
pub const FRAME_ID: &str = "lidar";

pub struct McapSink {
    path: PathBuf,
    writer: Option<mcap::Writer<BufWriter<std::fs::File>>>,
    detections: u16,
    points: Option<u16>,
    sequence: u32,
    buf: Vec<u8>,
}

fn channel<T: Encode>(path: &Path, w: &mut mcap::Writer<BufWriter<std::fs::File>>, topic: &str) -> Result<u16> {
    let schema = T::get_schema().ok_or_else(|| LiveError::invalid(path, format!("no schema for {topic}")))?;
    let err = |e: mcap::McapError| LiveError::invalid(path, format!("MCAP: {e}"));
    let id = w.add_schema(&schema.name, &schema.encoding, &schema.data).map_err(err)?;
    w.add_channel(id, topic, &T::get_message_encoding(), &Default::default()).map_err(err)
}

/// Distinct, readable colours per class name.
fn class_color(name: &str) -> Color {
    let (r, g, b) = match name {
        "Car" => (0.1, 0.6, 1.0),
        "Pedestrian" => (1.0, 0.3, 0.2),
        "Cyclist" => (1.0, 0.8, 0.1),
        other => {
            let h = other.bytes().fold(7u32, |h, c| h.wrapping_mul(31).wrapping_add(u32::from(c)));
            (f64::from(h % 7) / 7.0, f64::from(h / 7 % 5) / 5.0, 0.8)
        }
    };
    Color { r, g, b, a: 0.5 }
}

fn timestamp(ns: u64) -> Timestamp {
    Timestamp::new((ns / 1_000_000_000).min(u64::from(u32::MAX)) as u32, (ns % 1_000_000_000) as u32)
}

/// One sweep's boxes as a scene entity.
pub fn scene_update(objects: &[Object], stamp_ns: u64) -> SceneUpdate {
    let mut e = SceneEntity {
        timestamp: Some(timestamp(stamp_ns)),
        frame_id: FRAME_ID.into(),
        id: "detections".into(),
        ..Default::default()
    };
    for o in objects {
        let b = &o.box3d;
        let (s, c) = (0.5 * b.heading).sin_cos();
        let pose = Pose {
            position: Some(Vector3 { x: b.x, y: b.y, z: b.z }),
            orientation: Some(Quaternion { x: 0.0, y: 0.0, z: s, w: c }),
        };
        let color = class_color(&o.name);
        e.cubes.push(CubePrimitive {
            pose: Some(pose),
            size: Some(Vector3 { x: b.dx, y: b.dy, z: b.dz }),
            color: Some(color),
        });
        let top = Pose {
            position: Some(Vector3 { x: b.x, y: b.y, z: b.z + 0.5 * b.dz + 0.3 }),
            orientation: Some(Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }),
        };
        e.texts.push(TextPrimitive {
            pose: Some(top),
            billboard: true,
            font_size: 14.0,
            scale_invariant: true,
            color: Some(Color { a: 1.0, ..color }),
            text: match o.score {
                Some(s) => format!("{} {s:.2}", o.name),
                None => o.name.clone(),
            },
        });
    }
    SceneUpdate { deletions: Vec::new(), entities: vec![e] }
}

/// A sweep's x, y, z, intensity as a Foxglove point cloud.
pub fn point_cloud(frame: &LiveFrame) -> PointCloud {
    let pts = &frame.frame.points;
    let stride = pts.stride();
    let has_i = stride >= 4;
    let mut data = Vec::with_capacity(pts.len() * 16);
    for p in pts.iter() {
        for v in [p[0], p[1], p[2], if has_i { p[3] } else { 0.0 }] {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    let fields = ["x", "y", "z", "intensity"]
        .iter()
        .enumerate()
        .map(|(k, n)| PackedElementField {
            name: n.to_string(),
            offset: 4 * k as u32,
            r#type: NumericType::Float32 as i32,
        })
        .collect();
    PointCloud {
        timestamp: Some(timestamp(frame.stamp_ns)),
        frame_id: FRAME_ID.into(),
        pose: Some(Pose {
            position: Some(Vector3 { x: 0.0, y: 0.0, z: 0.0 }),
            orientation: Some(Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }),
        }),
        point_stride: 16,
        fields,
        data: foxglove::bytes::Bytes::from(data),
    }
}

impl McapSink {
    pub fn create(path: &Path, points: bool, overwrite: bool) -> Result<Self> {
        let file = create(path, overwrite)?;
        let mut w =
            mcap::Writer::new(BufWriter::new(file)).map_err(|e| LiveError::invalid(path, format!("MCAP: {e}")))?;
        let detections = channel::<SceneUpdate>(path, &mut w, DETECTIONS_TOPIC)?;
        let points = if points { Some(channel::<PointCloud>(path, &mut w, POINTS_TOPIC)?) } else { None };
        Ok(Self { path: path.to_path_buf(), writer: Some(w), detections, points, sequence: 0, buf: Vec::new() })
    }

    fn log<T: Encode>(&mut self, channel_id: u16, msg: &T, stamp_ns: u64) -> Result<()> {
        self.buf.clear();
        msg.encode(&mut self.buf).map_err(|e| LiveError::invalid(&self.path, format!("encoding: {e}")))?;
        let w = self.writer.as_mut().ok_or_else(|| LiveError::invalid(&self.path, "written after finish"))?;
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: stamp_ns,
            publish_time: stamp_ns,
        };
        w.write_to_known_channel(&header, &self.buf)
            .map_err(|e| LiveError::invalid(&self.path, format!("MCAP: {e}")))?;
        Ok(())
    }
}

impl Sink for McapSink {
    fn describe(&self) -> String {
        self.path.display().to_string()
    }

    fn write(&mut self, frame: &LiveFrame, objects: &[Object], _latency: &FrameLatency) -> Result<()> {
        self.log(self.detections, &scene_update(objects, frame.stamp_ns), frame.stamp_ns)?;
        if let Some(id) = self.points {
            self.log(id, &point_cloud(frame), frame.stamp_ns)?;
        }
        self.sequence += 1;
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        if let Some(mut w) = self.writer.take() {
            w.finish().map_err(|e| LiveError::invalid(&self.path, format!("MCAP: {e}")))?;
        }
        Ok(())
    }
}

impl Drop for McapSink {
    fn drop(&mut self) {
        // An interrupted run still leaves a file with its summary.
        let _ = self.finish();
    }
}
