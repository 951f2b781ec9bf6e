//! Point clouds and the raw float32 `.bin` files they are stored in.

use std::path::Path;

use crate::error::DataError;

/// `N × stride` float32 points; the first four channels are x, y, z, intensity. Extra channels
/// (nuScenes ring index, time…) are kept and named.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PointCloud {
    data: Vec<f32>,
    channels: Vec<String>,
}

impl PointCloud {
    pub const XYZI: [&'static str; 4] = ["x", "y", "z", "intensity"];

    /// From interleaved data; `channels.len()` is the stride (≥ 3).
    pub fn from_vec(data: Vec<f32>, channels: Vec<String>) -> Result<Self, DataError> {
        let stride = channels.len();
        if stride < 3 || !data.len().is_multiple_of(stride) {
            return Err(DataError::invalid(
                "<memory>",
                format!("{} values do not make points of {} channels", data.len(), stride),
            ));
        }
        Ok(Self { data, channels })
    }

    /// x, y, z, intensity points.
    pub fn from_xyzi(points: &[[f32; 4]]) -> Self {
        Self { data: points.iter().flatten().copied().collect(), channels: Self::xyzi_names() }
    }

    fn xyzi_names() -> Vec<String> {
        Self::XYZI.iter().map(|s| s.to_string()).collect()
    }

    pub fn len(&self) -> usize {
        self.data.len() / self.stride()
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    pub fn stride(&self) -> usize {
        self.channels.len()
    }

    pub fn channels(&self) -> &[String] {
        &self.channels
    }

    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }

    pub fn point(&self, i: usize) -> &[f32] {
        let s = self.stride();
        &self.data[i * s..(i + 1) * s]
    }

    pub fn iter(&self) -> impl ExactSizeIterator<Item = &[f32]> + '_ {
        self.data.chunks_exact(self.stride())
    }

    pub fn xyz_f64(&self) -> impl Iterator<Item = [f64; 3]> + '_ {
        self.iter().map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
    }

    /// Intensity (4th channel) when present.
    pub fn intensity(&self, i: usize) -> Option<f32> {
        (self.stride() > 3).then(|| self.point(i)[3])
    }

    /// Keeps the points for which `keep` is true.
    pub fn retain(&mut self, mut keep: impl FnMut(&[f32]) -> bool) {
        let s = self.stride();
        let mut out = Vec::with_capacity(self.data.len());
        for p in self.data.chunks_exact(s) {
            if keep(p) {
                out.extend_from_slice(p);
            }
        }
        self.data = out;
    }

    /// Only x, y, z, intensity (drops extra channels; adds zero intensity to xyz-only clouds).
    pub fn to_xyzi(&self) -> PointCloud {
        let mut data = Vec::with_capacity(self.len() * 4);
        for p in self.iter() {
            data.extend_from_slice(&[p[0], p[1], p[2], p.get(3).copied().unwrap_or(0.0)]);
        }
        PointCloud { data, channels: Self::xyzi_names() }
    }

    pub fn into_vec(self) -> Vec<f32> {
        self.data
    }
}

/// A `.bin` file read with a known stride, non-finite points dropped and counted.
pub struct BinRead {
    pub cloud: PointCloud,
    pub dropped_non_finite: usize,
}

/// Reads a float32 little-endian `.bin` with `channels.len()` values per point. A size that is not
/// a multiple of the point size is an error naming the file; points with a NaN or infinite
/// coordinate are dropped, counted, and reported once per file as a warning.
pub fn read_bin(path: &Path, channels: &[&str]) -> Result<BinRead, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    parse_bin(&bytes, channels, path)
}

/// [`read_bin`] of bytes already in memory; `path` names them in messages.
pub fn parse_bin(bytes: &[u8], channels: &[&str], path: &Path) -> Result<BinRead, DataError> {
    let stride = channels.len();
    if stride < 3 {
        return Err(DataError::invalid(path, format!("{stride} channels per point; x, y and z are needed")));
    }
    let point_bytes = 4 * stride;
    if !bytes.len().is_multiple_of(point_bytes) {
        return Err(DataError::invalid(
            path,
            format!(
                "size {} bytes is not a multiple of {point_bytes} ({stride} float32 per point): truncated or wrong stride",
                bytes.len()
            ),
        ));
    }
    let mut data = Vec::with_capacity(bytes.len() / 4);
    let mut dropped = 0usize;
    for p in bytes.chunks_exact(point_bytes) {
        let start = data.len();
        data.extend(p.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])));
        if !data[start..start + 3].iter().all(|v| v.is_finite()) {
            data.truncate(start);
            dropped += 1;
        }
    }
    if dropped > 0 {
        tracing::warn!("{}: dropped {dropped} points with a NaN or infinite coordinate", path.display());
    }
    let cloud = PointCloud { data, channels: channels.iter().map(|s| s.to_string()).collect() };
    Ok(BinRead { cloud, dropped_non_finite: dropped })
}

/// Writes points as float32 little-endian, atomically; refuses to replace an existing file unless
/// `overwrite`.
pub fn write_bin(path: &Path, cloud: &PointCloud, overwrite: bool) -> Result<(), DataError> {
    let mut bytes = Vec::with_capacity(cloud.as_slice().len() * 4);
    for v in cloud.as_slice() {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    crate::io::write_atomic(path, &bytes, overwrite)
}
