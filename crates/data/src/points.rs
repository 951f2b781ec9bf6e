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

/// The scale a format stores intensity in. Readers declare theirs (a `FrameInfo` field) and
/// [`crate::Dataset::load`] brings every frame to [`IntensityScale::Unit`], the scale of the Pi3DET
/// layout, KITTI, the sequence reader, the live sources and the simulator, so one model sees one
/// scale whatever the dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum IntensityScale {
    /// [0, 1]: KITTI reflectance, the Pi3DET layout (Ouster reflectivity / 255), the simulator.
    #[default]
    Unit,
    /// [0, 255]: nuScenes (and mmdet3d's nuScenes infos, which pass it through), 8-bit drivers.
    Byte,
}

impl IntensityScale {
    pub fn max(self) -> f32 {
        match self {
            IntensityScale::Unit => 1.0,
            IntensityScale::Byte => 255.0,
        }
    }
}

/// What a frame's intensity channel turned out to be once brought to [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum IntensityCheck {
    /// Varied values within the scale.
    Valid,
    /// No intensity channel.
    Absent,
    /// Every point has the same value: a converter that lost intensity (Argoverse's KITTI-format
    /// converter writes 1.0). The value carries no information about the surface.
    Constant(f32),
    /// Values outside [0, 255] before scaling (or negative): no known convention; clamped to [0, 1].
    OutOfScale { min: f32, max: f32 },
    /// This many points have a NaN or infinite intensity: set to 0 (the others are left as they
    /// are, so the scale is not checked).
    NonFinite(usize),
    /// Stored on the 0–255 scale though the format declares [0, 1] (a converter that kept a
    /// sensor's 8-bit values): divided by 255.
    ByteInUnitFormat,
}

impl PointCloud {
    /// Brings the intensity channel from `scale` to [0, 1] and says what it found. Frames declared
    /// [0, 1] whose values reach above 1 but stay within 255 are taken as 8-bit and divided too;
    /// values outside every known scale are clamped. One pass over the points.
    pub fn normalize_intensity(&mut self, scale: IntensityScale) -> IntensityCheck {
        let s = self.stride();
        if s < 4 || self.is_empty() {
            return IntensityCheck::Absent;
        }
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut non_finite = 0usize;
        for p in self.data.chunks_exact(s) {
            if p[3].is_finite() {
                lo = lo.min(p[3]);
                hi = hi.max(p[3]);
            } else {
                non_finite += 1;
            }
        }
        let mut check = IntensityCheck::Valid;
        let mut divide = match scale {
            IntensityScale::Unit => 1.0,
            IntensityScale::Byte => 255.0,
        };
        if non_finite > 0 {
            // NaN or infinite intensities (their points' coordinates are finite): set to 0.
            check = IntensityCheck::NonFinite(non_finite);
        } else if !(lo.is_finite() && lo >= 0.0 && hi <= 255.0) {
            check = IntensityCheck::OutOfScale { min: lo, max: hi };
        } else if scale == IntensityScale::Unit && hi > 1.0 {
            check = IntensityCheck::ByteInUnitFormat;
            divide = 255.0;
        }
        if divide != 1.0 || matches!(check, IntensityCheck::OutOfScale { .. } | IntensityCheck::NonFinite(_)) {
            for p in self.data.chunks_exact_mut(s) {
                let v = if p[3].is_finite() { p[3] / divide } else { 0.0 };
                p[3] = v.clamp(0.0, 1.0);
            }
        }
        if check == IntensityCheck::Valid && lo == hi && self.len() > 1 {
            check = IntensityCheck::Constant(lo / divide);
        }
        check
    }
}

/// Reports an intensity finding once per folder of point files, so a dataset of thousands of
/// frames written by one converter gives one line, not one per frame (or per point).
pub fn report_intensity(path: &Path, check: IntensityCheck) {
    use std::collections::HashSet;
    use std::sync::Mutex;
    static SEEN: Mutex<Option<HashSet<(std::path::PathBuf, u8)>>> = Mutex::new(None);
    let (kind, what) = match check {
        IntensityCheck::Valid | IntensityCheck::Absent => return,
        IntensityCheck::Constant(v) => (0, format!("every point has intensity {v}: the intensity was lost on the way (treated as missing by the detectors)")),
        IntensityCheck::OutOfScale { min, max } => {
            (1, format!("intensity spans {min}..{max}, outside every known scale ([0, 1], [0, 255]); clamped to [0, 1]"))
        }
        IntensityCheck::NonFinite(n) => (3, format!("{n} points have a NaN or infinite intensity: set to 0")),
        IntensityCheck::ByteInUnitFormat => {
            (2, "intensity reaches above 1 in a format that stores [0, 1]: taken as 8-bit (0–255) and divided by 255".to_string())
        }
    };
    let folder = path.parent().unwrap_or(path).to_path_buf();
    let mut seen = SEEN.lock().unwrap_or_else(|e| e.into_inner());
    if seen.get_or_insert_with(HashSet::new).insert((folder, kind)) {
        tracing::warn!("{}: {what} (reported once for this folder)", path.display());
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

#[cfg(test)]
mod intensity_tests {
    use super::*;

    fn cloud(i: &[f32]) -> PointCloud {
        PointCloud::from_xyzi(&i.iter().map(|&v| [1.0, 2.0, 3.0, v]).collect::<Vec<_>>())
    }

    fn intensities(c: &PointCloud) -> Vec<f32> {
        (0..c.len()).map(|k| c.intensity(k).unwrap()).collect()
    }

    #[test]
    fn scales_are_brought_to_zero_to_one() {
        let mut c = cloud(&[0.0, 0.5, 1.0]);
        assert_eq!(c.normalize_intensity(IntensityScale::Unit), IntensityCheck::Valid);
        assert_eq!(intensities(&c), [0.0, 0.5, 1.0]);
        let mut c = cloud(&[0.0, 51.0, 255.0]);
        assert_eq!(c.normalize_intensity(IntensityScale::Byte), IntensityCheck::Valid);
        assert_eq!(intensities(&c), [0.0, 0.2, 1.0]);
        // 8-bit values in a [0, 1] format: divided, and said so.
        let mut c = cloud(&[0.0, 51.0, 255.0]);
        assert_eq!(c.normalize_intensity(IntensityScale::Unit), IntensityCheck::ByteInUnitFormat);
        assert_eq!(intensities(&c), [0.0, 0.2, 1.0]);
    }

    #[test]
    fn lost_and_impossible_intensities_are_named() {
        let mut c = cloud(&[1.0, 1.0, 1.0]);
        assert_eq!(c.normalize_intensity(IntensityScale::Unit), IntensityCheck::Constant(1.0));
        let mut c = cloud(&[-3.0, 100.0, 4000.0]);
        assert_eq!(c.normalize_intensity(IntensityScale::Byte), IntensityCheck::OutOfScale { min: -3.0, max: 4000.0 });
        assert!(intensities(&c).iter().all(|v| (0.0..=1.0).contains(v)));
        let mut nan = cloud(&[0.5, f32::NAN, 0.25]);
        assert_eq!(nan.normalize_intensity(IntensityScale::Unit), IntensityCheck::NonFinite(1));
        assert_eq!(intensities(&nan), [0.5, 0.0, 0.25]);
        let mut xyz = PointCloud::from_vec(vec![1.0, 2.0, 3.0], vec!["x".into(), "y".into(), "z".into()]).unwrap();
        assert_eq!(xyz.normalize_intensity(IntensityScale::Unit), IntensityCheck::Absent);
    }
}
