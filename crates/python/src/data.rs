//! `pi3det.data`: `open(path)` on every format the Rust readers take, as a lazy, indexable
//! sequence of `Frame`s whose points numpy receives without a copy.

use std::path::PathBuf;
use std::sync::Arc;

use pi3det_data::{Frame as RustFrame, FrameInfo, PointCloud};
use pi3det_geometry::PoseExt;
use pi3det_sequence::SequenceOptions;
use pyo3::exceptions::{PyIndexError, PyStopIteration};
use pyo3::prelude::*;

use crate::arrays::{matrix, str_array};
use crate::error;

/// One LiDAR frame: `points` `float32 (N, C)` (x, y, z, intensity, then `channels[4:]`),
/// `boxes` `float64 (M, 7)` `[x, y, z_center, dx, dy, dz, heading]` in the LiDAR frame, `names`
/// (numpy str), `scores` (detections only), `num_points` per box where the dataset stores it
/// (-1 where not), `pose` the `world_from_lidar` 4×4 matrix where known.
#[pyclass(module = "pi3det", frozen, get_all)]
pub struct Frame {
    id: String,
    platform: String,
    sequence: Option<String>,
    timestamp: Option<f64>,
    points: Option<Py<PyAny>>,
    channels: Vec<String>,
    boxes: Py<PyAny>,
    names: Py<PyAny>,
    scores: Option<Py<PyAny>>,
    num_points: Py<PyAny>,
    pose: Option<Py<PyAny>>,
    points_path: Option<PathBuf>,
}

#[pymethods]
impl Frame {
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let n = |o: &Py<PyAny>| -> PyResult<usize> { o.bind(py).len() };
        let points = match &self.points {
            Some(p) => format!("{} points", n(p)?),
            None => "no points loaded".to_string(),
        };
        Ok(format!(
            "Frame(id={:?}, platform={:?}, sequence={:?}, {points}, {} boxes)",
            self.id,
            self.platform,
            self.sequence.as_deref().unwrap_or(""),
            n(&self.boxes)?
        ))
    }
}

impl Frame {
    /// Moves the frame into Python: the point buffer becomes the numpy array's memory.
    pub fn from_rust(py: Python<'_>, info: FrameInfo, points: Option<PointCloud>) -> PyResult<Self> {
        let channels = match &points {
            Some(p) => p.channels().to_vec(),
            None => info.point_channels.clone(),
        };
        let points = match points {
            Some(p) => {
                let stride = p.stride();
                Some(matrix(py, p.into_vec(), stride)?.unbind())
            }
            None => None,
        };
        let objects = &info.objects;
        let boxes: Vec<f64> = objects.iter().flat_map(|o| o.box3d.to_array()).collect();
        let scored = !objects.is_empty() && objects.iter().all(|o| o.score.is_some());
        let scores = if scored {
            let s: Vec<f64> = objects.iter().map(|o| o.score.unwrap_or(0.0)).collect();
            Some(matrix(py, s, 1)?.call_method1("reshape", (-1,))?.unbind())
        } else {
            None
        };
        let num_points: Vec<i64> = objects.iter().map(|o| o.num_points.map_or(-1, i64::from)).collect();
        let pose = match &info.world_from_lidar {
            Some(p) => Some(matrix(py, p.to_matrix_rows().concat(), 4)?.unbind()),
            None => None,
        };
        Ok(Self {
            id: info.id,
            platform: info.platform.as_str().to_string(),
            sequence: info.sequence,
            timestamp: info.timestamp_s,
            points,
            channels,
            boxes: matrix(py, boxes, 7)?.unbind(),
            names: str_array(py, objects.iter().map(|o| o.name.clone()).collect())?.unbind(),
            scores,
            num_points: matrix(py, num_points, 1)?.call_method1("reshape", (-1,))?.unbind(),
            pose,
            points_path: (!info.points_path.as_os_str().is_empty()).then_some(info.points_path),
        })
    }

    pub fn from_frame(py: Python<'_>, f: RustFrame) -> PyResult<Self> {
        Self::from_rust(py, f.info, Some(f.points))
    }
}

/// A dataset opened by `pi3det.data.open`: `len(ds)`, `ds[i]` (a `Frame` with points, negative
/// indices count from the end), iteration, and `ds.info(i)` (annotations without points).
#[pyclass(module = "pi3det", frozen, sequence)]
pub struct Dataset {
    inner: Arc<dyn pi3det_data::Dataset>,
}

impl Dataset {
    fn index(&self, i: isize) -> PyResult<usize> {
        let n = self.inner.len() as isize;
        let j = if i < 0 { i + n } else { i };
        if (0..n).contains(&j) {
            Ok(j as usize)
        } else {
            Err(PyIndexError::new_err(format!("frame index {i} out of range for {n} frames")))
        }
    }
}

#[pymethods]
impl Dataset {
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __getitem__(&self, py: Python<'_>, index: isize) -> PyResult<Frame> {
        let i = self.index(index)?;
        let ds = self.inner.clone();
        let f = py.detach(move || ds.load(i)).map_err(error::data)?;
        Frame::from_frame(py, f)
    }

    /// The frame's annotations and pose without reading its points (`points` is None).
    fn info(&self, py: Python<'_>, index: isize) -> PyResult<Frame> {
        let i = self.index(index)?;
        let ds = self.inner.clone();
        let info = py.detach(move || ds.info(i)).map_err(error::data)?;
        Frame::from_rust(py, info, None)
    }

    fn __iter__(slf: Py<Self>) -> DatasetIter {
        DatasetIter { dataset: slf, next: std::sync::atomic::AtomicUsize::new(0) }
    }

    /// `pi3det`, `kitti` or `nuscenes` (the sequence release reads as `pi3det`).
    #[getter]
    fn format(&self) -> String {
        format!("{:?}", self.inner.format()).to_lowercase()
    }

    #[getter]
    fn root(&self) -> PathBuf {
        self.inner.root().to_path_buf()
    }

    fn __repr__(&self) -> String {
        format!("Dataset(format={:?}, root={:?}, frames={})", self.format(), self.inner.root(), self.inner.len())
    }
}

#[pyclass(module = "pi3det", frozen)]
pub struct DatasetIter {
    dataset: Py<Dataset>,
    next: std::sync::atomic::AtomicUsize,
}

#[pymethods]
impl DatasetIter {
    fn __iter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Frame> {
        let ds = self.dataset.get();
        let i = self.next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if i >= ds.inner.len() {
            return Err(PyStopIteration::new_err(()));
        }
        ds.__getitem__(py, i as isize)
    }
}

/// Opens a dataset, detecting its format: a Pi3DET root or info `.pkl`, a KITTI folder, an
/// mmdet3d nuScenes info `.pkl`, or sequences of the full Pi3DET release (HDF5).
#[pyfunction]
pub fn open(py: Python<'_>, path: PathBuf) -> PyResult<Dataset> {
    let ds = py.detach(|| pi3det_sequence::open(&path, SequenceOptions::default())).map_err(error::data)?;
    Ok(Dataset { inner: Arc::from(ds) })
}
