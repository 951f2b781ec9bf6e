//! ROS 2 `sensor_msgs/msg/PointCloud2` in CDR (the ROS 2 wire and bag encoding) → points.
//!
//! Any common layout: `x`/`y`/`z` as float32 or float64; intensity from a field named
//! `intensity` (else `reflectivity`) of any numeric type; other fields ignored. Intensity is put
//! on the [0, 1] scale our datasets use: 8-bit integers / 255; wider integers are reflectivity
//! (clamped to 255, / 255, as the sequence reader does); floats as they are, unless the cloud
//! has values above 1 (0–255 drivers), then / 255 clamped. Non-finite points (how organized
//! clouds mark missing returns) are dropped and counted.

use pi3det_data::PointCloud;

/// One `sensor_msgs/msg/PointField`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PointField {
    pub name: String,
    pub offset: u32,
    pub datatype: u8,
    pub count: u32,
}

pub const INT8: u8 = 1;
pub const UINT8: u8 = 2;
pub const INT16: u8 = 3;
pub const UINT16: u8 = 4;
pub const INT32: u8 = 5;
pub const UINT32: u8 = 6;
pub const FLOAT32: u8 = 7;
pub const FLOAT64: u8 = 8;

fn type_size(datatype: u8) -> Option<usize> {
    Some(match datatype {
        INT8 | UINT8 => 1,
        INT16 | UINT16 => 2,
        INT32 | UINT32 | FLOAT32 => 4,
        FLOAT64 => 8,
        _ => return None,
    })
}

/// A decoded cloud message.
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud2 {
    pub stamp_ns: u64,
    pub frame_id: String,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub is_bigendian: bool,
    pub point_step: u32,
    pub row_step: u32,
    pub data: Vec<u8>,
    pub is_dense: bool,
}

/// Little/big-endian CDR reader (XCDR1: primitives aligned to their size from the start of the
/// payload, after the 4-byte encapsulation header).
struct Cdr<'a> {
    buf: &'a [u8],
    pos: usize,
    le: bool,
}

impl<'a> Cdr<'a> {
    fn new(msg: &'a [u8]) -> Result<Self, String> {
        if msg.len() < 4 {
            return Err(format!("{} bytes: shorter than the CDR encapsulation header", msg.len()));
        }
        let le = match (msg[0], msg[1]) {
            (0, 1) | (0, 3) => true,
            (0, 0) | (0, 2) => false,
            (a, b) => return Err(format!("unknown CDR encapsulation {a:#04x}{b:02x}")),
        };
        Ok(Self { buf: &msg[4..], pos: 0, le })
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len()).ok_or_else(|| {
            format!("truncated at {what}: needs {n} bytes at offset {}, message has {}", self.pos, self.buf.len())
        })?;
        let s = &self.buf[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn align(&mut self, n: usize) {
        self.pos = self.pos.div_ceil(n) * n;
    }

    fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.align(4);
        let b: [u8; 4] = self.take(4, what)?.try_into().expect("4 bytes");
        Ok(if self.le { u32::from_le_bytes(b) } else { u32::from_be_bytes(b) })
    }

    fn string(&mut self, what: &str) -> Result<String, String> {
        let n = self.u32(what)? as usize;
        let b = self.take(n, what)?;
        let b = b.strip_suffix(&[0]).unwrap_or(b);
        String::from_utf8(b.to_vec()).map_err(|_| format!("{what}: not UTF-8"))
    }
}

/// Little-endian CDR writer (alignment counted after the 4-byte encapsulation header).
struct CdrWriter(Vec<u8>);

impl CdrWriter {
    fn u32(&mut self, v: u32) {
        while !(self.0.len() - 4).is_multiple_of(4) {
            self.0.push(0);
        }
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
}

impl PointCloud2 {
    /// Decodes a CDR-encoded message (as stored in a ROS 2 MCAP bag).
    pub fn decode(msg: &[u8]) -> Result<Self, String> {
        let mut c = Cdr::new(msg)?;
        let sec = c.u32("header.stamp.sec")? as i32;
        let nanosec = c.u32("header.stamp.nanosec")?;
        let frame_id = c.string("header.frame_id")?;
        let height = c.u32("height")?;
        let width = c.u32("width")?;
        let n_fields = c.u32("fields")? as usize;
        if n_fields > 1024 {
            return Err(format!("{n_fields} point fields: not a point cloud"));
        }
        let mut fields = Vec::with_capacity(n_fields);
        for _ in 0..n_fields {
            let name = c.string("field name")?;
            let offset = c.u32("field offset")?;
            let datatype = c.u8("field datatype")?;
            let count = c.u32("field count")?;
            fields.push(PointField { name, offset, datatype, count });
        }
        let is_bigendian = c.u8("is_bigendian")? != 0;
        let point_step = c.u32("point_step")?;
        let row_step = c.u32("row_step")?;
        let n = c.u32("data")? as usize;
        let data = c.take(n, "data")?.to_vec();
        let is_dense = c.u8("is_dense").map(|b| b != 0).unwrap_or(true);
        let stamp_ns = (i64::from(sec) * 1_000_000_000 + i64::from(nanosec)).max(0) as u64;
        Ok(Self { stamp_ns, frame_id, height, width, fields, is_bigendian, point_step, row_step, data, is_dense })
    }

    /// Encodes as little-endian CDR (for tests and replays).
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter(vec![0u8, 1, 0, 0]);
        w.u32((self.stamp_ns / 1_000_000_000) as u32);
        w.u32((self.stamp_ns % 1_000_000_000) as u32);
        w.string(&self.frame_id);
        w.u32(self.height);
        w.u32(self.width);
        w.u32(self.fields.len() as u32);
        for f in &self.fields {
            w.string(&f.name);
            w.u32(f.offset);
            w.0.push(f.datatype);
            w.u32(f.count);
        }
        w.0.push(u8::from(self.is_bigendian));
        w.u32(self.point_step);
        w.u32(self.row_step);
        w.u32(self.data.len() as u32);
        w.0.extend_from_slice(&self.data);
        w.0.push(u8::from(self.is_dense));
        w.0
    }

    fn field(&self, names: &[&str]) -> Option<&PointField> {
        names.iter().find_map(|n| self.fields.iter().find(|f| f.name == *n))
    }

    /// The points as `x, y, z, intensity` and how many non-finite ones were dropped.
    pub fn to_points(&self) -> Result<(PointCloud, usize), String> {
        let names: Vec<&str> = self.fields.iter().map(|f| f.name.as_str()).collect();
        let axis = |n: &str| -> Result<&PointField, String> {
            let f = self.field(&[n]).ok_or_else(|| format!("no '{n}' field (fields: {})", names.join(", ")))?;
            if !matches!(f.datatype, FLOAT32 | FLOAT64) {
                return Err(format!("field '{n}' has datatype {}, expected float32 (7) or float64 (8)", f.datatype));
            }
            Ok(f)
        };
        let (fx, fy, fz) = (axis("x")?, axis("y")?, axis("z")?);
        let fi = self.field(&["intensity", "reflectivity"]);
        let step = self.point_step as usize;
        for f in [Some(fx), Some(fy), Some(fz), fi].into_iter().flatten() {
            let size =
                type_size(f.datatype).ok_or_else(|| format!("field '{}': unknown datatype {}", f.name, f.datatype))?;
            if f.offset as usize + size > step {
                return Err(format!("field '{}' ends past point_step {step}", f.name));
            }
        }
        let (h, w) = (self.height as usize, self.width as usize);
        let row = self.row_step as usize;
        if w > 0 && row < w.saturating_mul(step) {
            return Err(format!("row_step {row} < width {w} × point_step {step}"));
        }
        let need = h.checked_mul(row).ok_or("height × row_step overflows")?;
        if h > 0 && w > 0 && self.data.len() < need {
            return Err(format!("data has {} bytes, height {h} × row_step {row} needs {need}", self.data.len()));
        }
        let be = self.is_bigendian;
        let read =
            |base: usize, f: &PointField| -> f64 { read_value(&self.data[base + f.offset as usize..], f.datatype, be) };
        let mut out = Vec::with_capacity(h * w * 4);
        let mut dropped = 0;
        for r in 0..h {
            for c in 0..w {
                let base = r * row + c * step;
                let (x, y, z) = (read(base, fx), read(base, fy), read(base, fz));
                let i = fi.map_or(0.0, |f| read(base, f));
                if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                    dropped += 1;
                    continue;
                }
                out.extend_from_slice(&[x as f32, y as f32, z as f32, if i.is_finite() { i as f32 } else { 0.0 }]);
            }
        }
        if let Some(f) = fi {
            let scale_floats = out.chunks_exact(4).any(|p| p[3] > 1.0);
            for p in out.chunks_exact_mut(4) {
                p[3] = match f.datatype {
                    INT8 | UINT8 => p[3] / 255.0,
                    FLOAT32 | FLOAT64 if !scale_floats => p[3],
                    _ => p[3].clamp(0.0, 255.0) / 255.0,
                };
            }
        }
        let cloud = PointCloud::from_vec(out, ["x", "y", "z", "intensity"].map(String::from).to_vec())
            .map_err(|e| e.to_string())?;
        Ok((cloud, dropped))
    }
}

fn read_value(b: &[u8], datatype: u8, be: bool) -> f64 {
    macro_rules! num {
        ($t:ty) => {{
            let a: [u8; std::mem::size_of::<$t>()] = b[..std::mem::size_of::<$t>()].try_into().expect("size checked");
            (if be { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as f64
        }};
    }
    match datatype {
        INT8 => num!(i8),
        UINT8 => num!(u8),
        INT16 => num!(i16),
        UINT16 => num!(u16),
        INT32 => num!(i32),
        UINT32 => num!(u32),
        FLOAT32 => num!(f32),
        FLOAT64 => num!(f64),
        _ => f64::NAN,
    }
}

/// A dense cloud of `x, y, z, intensity` float32 points (for tests and replays).
pub fn from_xyzi(points: &[[f32; 4]], stamp_ns: u64, frame_id: &str) -> PointCloud2 {
    let fields = ["x", "y", "z", "intensity"]
        .iter()
        .enumerate()
        .map(|(k, n)| PointField { name: n.to_string(), offset: 4 * k as u32, datatype: FLOAT32, count: 1 })
        .collect();
    let data = points.iter().flat_map(|p| p.iter().flat_map(|v| v.to_le_bytes())).collect();
    PointCloud2 {
        stamp_ns,
        frame_id: frame_id.into(),
        height: 1,
        width: points.len() as u32,
        fields,
        is_bigendian: false,
        point_step: 16,
        row_step: 16 * points.len() as u32,
        data,
        is_dense: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_points() {
        let pts = [[1.0, 2.0, 3.0, 0.5], [-4.0, 5.5, -0.25, 1.0]];
        let msg = from_xyzi(&pts, 1_700_000_000_123_456_789, "os_lidar");
        let back = PointCloud2::decode(&msg.encode()).unwrap();
        assert_eq!(back, msg);
        let (cloud, dropped) = back.to_points().unwrap();
        assert_eq!(dropped, 0);
        assert_eq!(cloud.as_slice(), pts.concat().as_slice());
    }

    #[test]
    fn ouster_layout_with_u16_reflectivity_and_nan() {
        // x y z (f32) + padding + intensity f32 + t u32 + reflectivity u16 + ring u16 …, 48 bytes.
        let mut fields = Vec::new();
        for (name, offset, datatype) in [
            ("x", 0, FLOAT32),
            ("y", 4, FLOAT32),
            ("z", 8, FLOAT32),
            ("t", 20, UINT32),
            ("reflectivity", 24, UINT16),
            ("ring", 26, UINT16),
        ] {
            fields.push(PointField { name: name.into(), offset, datatype, count: 1 });
        }
        let mut data = vec![0u8; 48 * 2];
        for (k, (xyz, refl)) in [([1.0f32, 0.0, 0.0], 510u16), ([f32::NAN, 0.0, 0.0], 3)].iter().enumerate() {
            for (j, v) in xyz.iter().enumerate() {
                data[48 * k + 4 * j..48 * k + 4 * j + 4].copy_from_slice(&v.to_le_bytes());
            }
            data[48 * k + 24..48 * k + 26].copy_from_slice(&refl.to_le_bytes());
        }
        let msg = PointCloud2 {
            stamp_ns: 0,
            frame_id: "f".into(),
            height: 2,
            width: 1,
            fields,
            is_bigendian: false,
            point_step: 48,
            row_step: 48,
            data,
            is_dense: false,
        };
        let (cloud, dropped) = PointCloud2::decode(&msg.encode()).unwrap().to_points().unwrap();
        assert_eq!(dropped, 1);
        assert_eq!(cloud.as_slice(), &[1.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn bad_clouds_are_errors() {
        let mut msg = from_xyzi(&[[0.0; 4]], 0, "f");
        msg.fields.retain(|f| f.name != "z");
        let e = PointCloud2::decode(&msg.encode()).unwrap().to_points().unwrap_err();
        assert!(e.contains("no 'z' field (fields: x, y, intensity)"), "{e}");
        let mut msg = from_xyzi(&[[0.0; 4]; 3], 0, "f");
        msg.data.truncate(20);
        let e = PointCloud2::decode(&msg.encode()).unwrap().to_points().unwrap_err();
        assert!(e.contains("needs 48"), "{e}");
        let bytes = from_xyzi(&[[0.0; 4]; 3], 0, "f").encode();
        for cut in [0, 3, 10, 60, bytes.len() - 30] {
            assert!(PointCloud2::decode(&bytes[..cut]).is_err(), "cut {cut}");
        }
    }
}
