//! Datasets as lazy, indexable collections of frames, and format detection.

use std::path::Path;

use crate::error::DataError;
use crate::frame::{Frame, FrameInfo};
use crate::points::{read_bin, PointCloud};

/// The on-disk formats pi3det reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    Pi3det,
    Kitti,
    Nuscenes,
}

/// A dataset: an index of frames whose points are read only when a frame is loaded.
/// Implementations are cheap to share across threads.
pub trait Dataset: Send + Sync {
    fn format(&self) -> Format;
    fn root(&self) -> &Path;
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Frame metadata and annotations, without points.
    fn info(&self, index: usize) -> Result<FrameInfo, DataError>;
    /// Every frame's info, in dataset order (read in parallel).
    fn infos(&self) -> Result<Vec<FrameInfo>, DataError> {
        use rayon::prelude::*;
        (0..self.len()).into_par_iter().map(|i| self.info(i)).collect()
    }
    /// The frame with its points (non-finite points dropped, see [`read_bin`]), intensity brought
    /// from the format's scale to [0, 1] ([`PointCloud::normalize_intensity`]; findings reported
    /// once per folder).
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let info = self.info(index)?;
        let channels: Vec<&str> = info.point_channels.iter().map(String::as_str).collect();
        let mut points = read_bin(&info.points_path, &channels)?.cloud;
        crate::points::report_intensity(&info.points_path, points.normalize_intensity(info.intensity_scale));
        Ok(Frame { info, points })
    }
}

/// How [`Mapped`] changes each frame of the dataset it wraps.
pub trait FrameMap: Send + Sync {
    /// The info of frame `index` (also the loaded frame's).
    fn info(&self, index: usize, info: FrameInfo) -> FrameInfo;
    /// The loaded frame's points (default: unchanged).
    fn points(&self, _index: usize, points: PointCloud) -> Result<PointCloud, DataError> {
        Ok(points)
    }
}

/// A dataset seen through a [`FrameMap`] (relabelled, moved): `info` and `load` both go through
/// the map, and `load` reads the points through the inner dataset (whatever its storage).
pub struct Mapped<M> {
    pub inner: std::sync::Arc<dyn Dataset>,
    pub map: M,
}

impl<M: FrameMap> Dataset for Mapped<M> {
    fn format(&self) -> Format {
        self.inner.format()
    }
    fn root(&self) -> &Path {
        self.inner.root()
    }
    fn len(&self) -> usize {
        self.inner.len()
    }
    fn info(&self, index: usize) -> Result<FrameInfo, DataError> {
        Ok(self.map.info(index, self.inner.info(index)?))
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let f = self.inner.load(index)?;
        Ok(Frame { info: self.map.info(index, f.info), points: self.map.points(index, f.points)? })
    }
}

/// Opens a dataset, detecting its format: a folder with `pi3det_infos_*.pkl`, a KITTI folder (with
/// `velodyne/`, or `training/velodyne/`), a Pi3DET info `.pkl`, or an mmdet3d nuScenes info `.pkl`.
/// A folder holding exactly one mmdet3d info file is opened through it.
pub fn open(path: &Path) -> Result<Box<dyn Dataset>, DataError> {
    use crate::{kitti::KittiDataset, nuscenes, pi3det};
    if !path.exists() {
        return Err(DataError::io(path, std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder")));
    }
    if path.is_dir() {
        if !pi3det::info_files(path)?.is_empty() {
            return Ok(Box::new(pi3det::Pi3detDataset::open(path)?));
        }
        if path.join("velodyne").is_dir() || path.join("training/velodyne").is_dir() {
            return Ok(Box::new(KittiDataset::open(path)?));
        }
        let pkls: Vec<_> = std::fs::read_dir(path)
            .map_err(|e| DataError::io(path, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "pkl"))
            .collect();
        if let [one] = pkls.as_slice() {
            return open(one);
        }
        // The full sequence release is read by pi3det-sequence (which depends on this crate).
        if looks_like_sequences(path) {
            return Err(DataError::UnknownFormat {
                path: path.to_path_buf(),
                hint: "this looks like the full Pi3DET sequence release (*data*.h5): run `pi3det convert PATH --to pi3det-layout --out DIR` first (`pi3det info` reads it directly)".into(),
            });
        }
        return Err(DataError::UnknownFormat {
            path: path.to_path_buf(),
            hint: "expected pi3det_infos_*.pkl, a KITTI velodyne/ folder, or one mmdet3d info .pkl".into(),
        });
    }
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    if name.starts_with("pi3det_infos_") {
        return Ok(Box::new(pi3det::Pi3detDataset::open(path)?));
    }
    if name.ends_with(".pkl") {
        // Decide by content: a list of info dicts is Pi3DET, a metainfo/data_list dict is mmdet3d.
        let value =
            crate::pickle::from_path(path).map_err(|source| DataError::Pickle { path: path.to_path_buf(), source })?;
        if nuscenes::looks_like_mmdet3d(&value) {
            return Ok(Box::new(nuscenes::NuscenesDataset::from_value(path, &value, None)?));
        }
        if value.as_list().is_some() {
            return Ok(Box::new(pi3det::Pi3detDataset::from_value(path, &value)?));
        }
    }
    Err(DataError::UnknownFormat { path: path.to_path_buf(), hint: "unrecognised file".into() })
}

/// A `processed/` folder, or a folder with a `*data*.h5` file (an M3ED-style sequence).
fn looks_like_sequences(path: &Path) -> bool {
    path.join("processed").is_dir()
        || std::fs::read_dir(path).is_ok_and(|d| {
            d.filter_map(|e| e.ok()).any(|e| {
                let n = e.file_name().to_string_lossy().into_owned();
                n.ends_with(".h5") && n.contains("data") || matches!(n.as_str(), "Car" | "Falcon" | "Spot")
            })
        })
}

#[cfg(test)]
mod tests {
    #[test]
    fn sequence_folders_point_at_convert() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("car_x_data.h5"), b"").unwrap();
        let e = super::open(dir.path()).err().unwrap().to_string();
        assert!(e.contains("pi3det convert"), "{e}");
    }
}

#[cfg(test)]
mod mapped_tests {
    use super::*;
    use std::path::PathBuf;

    /// Frames held in memory: `load` never touches a file.
    struct InMemory(PathBuf);

    impl Dataset for InMemory {
        fn format(&self) -> Format {
            Format::Pi3det
        }
        fn root(&self) -> &Path {
            &self.0
        }
        fn len(&self) -> usize {
            2
        }
        fn info(&self, index: usize) -> Result<FrameInfo, DataError> {
            Ok(FrameInfo::new(format!("{index}"), self.0.join("missing.bin")))
        }
        fn load(&self, index: usize) -> Result<Frame, DataError> {
            Ok(Frame { info: self.info(index)?, points: PointCloud::from_xyzi(&[[index as f32, 0.0, 0.0, 1.0]]) })
        }
    }

    struct Rename;

    impl FrameMap for Rename {
        fn info(&self, index: usize, mut info: FrameInfo) -> FrameInfo {
            info.id = format!("mapped-{index}");
            info
        }
    }

    #[test]
    fn load_goes_through_the_inner_dataset_and_the_map() {
        let m = Mapped { inner: std::sync::Arc::new(InMemory(PathBuf::from("/nowhere"))), map: Rename };
        let f = m.load(1).unwrap();
        assert_eq!(f.info.id, "mapped-1");
        assert_eq!(f.points.as_slice(), &[1.0, 0.0, 0.0, 1.0]);
        assert_eq!(m.info(0).unwrap().id, "mapped-0");
    }
}
