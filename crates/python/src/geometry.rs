//! `pi3det.geometry`: exact rotated IoU (polygon clipping in f64) between two box sets, and
//! OpenPCDet's class-agnostic rotated NMS.

use numpy::IntoPyArray;
use pi3det_geometry::{bev_iou_matrix, iou_3d_matrix, Box3d, IouMatrix, NmsConfig};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::arrays::{boxes, matrix, vector};

fn pair(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<(Vec<Box3d>, Vec<Box3d>)> {
    Ok((boxes(a, &|| "boxes_a".into())?, boxes(b, &|| "boxes_b".into())?))
}

fn out(py: Python<'_>, m: IouMatrix) -> PyResult<Bound<'_, PyAny>> {
    let (rows, cols) = (m.rows, m.cols);
    matrix(py, m.data, cols.max(1))?.call_method1("reshape", ((rows, cols),))
}

/// Bird's-eye-view IoU of every box of `boxes_a` `(N, 7)` with every box of `boxes_b` `(M, 7)`:
/// `float64 (N, M)`.
#[pyfunction]
pub fn rotated_iou_bev<'py>(
    py: Python<'py>,
    boxes_a: &Bound<'py, PyAny>,
    boxes_b: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let (a, b) = pair(boxes_a, boxes_b)?;
    out(py, py.detach(|| bev_iou_matrix(&a, &b)))
}

/// 3-D IoU (BEV intersection × height overlap) of every pair: `float64 (N, M)`.
#[pyfunction]
pub fn iou_3d<'py>(
    py: Python<'py>,
    boxes_a: &Bound<'py, PyAny>,
    boxes_b: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let (a, b) = pair(boxes_a, boxes_b)?;
    out(py, py.detach(|| iou_3d_matrix(&a, &b)))
}

/// OpenPCDet's `class_agnostic_nms`: drop scores below `score_threshold`, keep the
/// `pre_max_size` best, suppress boxes whose BEV IoU with a kept box is above `iou_threshold`;
/// returns `int64` indices into `boxes`, best first, at most `post_max_size`.
#[pyfunction]
#[pyo3(signature = (boxes, scores, iou_threshold, score_threshold=None, pre_max_size=None, post_max_size=None))]
pub fn nms<'py>(
    py: Python<'py>,
    boxes: &Bound<'py, PyAny>,
    scores: &Bound<'py, PyAny>,
    iou_threshold: f64,
    score_threshold: Option<f64>,
    pre_max_size: Option<usize>,
    post_max_size: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let b = crate::arrays::boxes(boxes, &|| "boxes".into())?;
    let s = vector(scores, &|| "scores".into())?;
    if s.len() != b.len() {
        return Err(PyValueError::new_err(format!("{} boxes but {} scores", b.len(), s.len())));
    }
    if let Some(i) = s.iter().position(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(format!("scores[{i}] is not finite: {}", s[i])));
    }
    if !(0.0..=1.0).contains(&iou_threshold) {
        return Err(PyValueError::new_err(format!("iou_threshold {iou_threshold} is not in [0, 1]")));
    }
    let cfg = NmsConfig {
        iou_threshold,
        score_threshold: score_threshold.unwrap_or(f64::NEG_INFINITY),
        pre_max_size: pre_max_size.unwrap_or(usize::MAX),
        post_max_size: post_max_size.unwrap_or(usize::MAX),
    };
    let keep: Vec<i64> = py.detach(|| pi3det_geometry::nms(&b, &s, &cfg)).into_iter().map(|i| i as i64).collect();
    Ok(keep.into_pyarray(py).into_any())
}
