//! numpy in and out: any numeric array as f64 (OpenPCDet mixes int64, float32 and float64 in one
//! annotation dict), boxes `(N, 7)`, and Rust vectors handed to numpy without a copy.

use numpy::ndarray::ArrayViewD;
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn};
use pi3det_geometry::Box3d;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// `obj` as a read-only f64 array: the array itself when it already is one, else
/// `numpy.asarray(obj, dtype=float64)` (lists, int and float32 arrays).
pub fn f64_array<'py>(obj: &Bound<'py, PyAny>) -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
    if let Ok(a) = obj.cast::<PyArrayDyn<f64>>() {
        return Ok(a.readonly());
    }
    let np = obj.py().import("numpy")?;
    let a = np.call_method1("asarray", (obj, "float64"))?;
    Ok(a.cast_into::<PyArrayDyn<f64>>().map_err(PyErr::from)?.readonly())
}

/// Checks the shape: `None` in `want` matches any length.
pub fn check_shape(view: &ArrayViewD<'_, f64>, want: &[Option<usize>], what: &dyn Fn() -> String) -> PyResult<()> {
    let ok = view.ndim() == want.len() && view.shape().iter().zip(want).all(|(&n, w)| w.is_none_or(|w| w == n));
    if ok {
        Ok(())
    } else {
        let want: Vec<String> = want.iter().map(|w| w.map_or("N".to_string(), |n| n.to_string())).collect();
        Err(PyValueError::new_err(format!("{}: expected shape ({}), got {:?}", what(), want.join(", "), view.shape())))
    }
}

/// Rows of an `(N, K)` array (a `(0,)` array counts as no rows, as numpy's empty annotations
/// often are).
pub fn rows<const K: usize>(obj: &Bound<'_, PyAny>, what: &dyn Fn() -> String) -> PyResult<Vec<[f64; K]>> {
    let a = f64_array(obj)?;
    let v = a.as_array();
    if v.is_empty() && v.ndim() <= 2 {
        return Ok(Vec::new());
    }
    check_shape(&v, &[None, Some(K)], what)?;
    let v = v.into_dimensionality::<numpy::ndarray::Ix2>().map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(v.outer_iter().map(|r| std::array::from_fn(|k| r[k])).collect())
}

/// A 1-D array of numbers.
pub fn vector(obj: &Bound<'_, PyAny>, what: &dyn Fn() -> String) -> PyResult<Vec<f64>> {
    let a = f64_array(obj)?;
    let v = a.as_array();
    if v.is_empty() && v.ndim() <= 2 {
        return Ok(Vec::new());
    }
    check_shape(&v, &[None], what)?;
    Ok(v.iter().copied().collect())
}

/// `(N, 7)` boxes `[x, y, z, dx, dy, dz, heading]`, finite with sizes ≥ 0.
pub fn boxes(obj: &Bound<'_, PyAny>, what: &dyn Fn() -> String) -> PyResult<Vec<Box3d>> {
    rows::<7>(obj, what)?
        .into_iter()
        .enumerate()
        .map(|(i, a)| Box3d::try_from_array(a).map_err(|e| PyValueError::new_err(format!("{} row {i}: {e}", what()))))
        .collect()
}

/// Strings of a list or a numpy array of str.
pub fn strings(obj: &Bound<'_, PyAny>, what: &dyn Fn() -> String) -> PyResult<Vec<String>> {
    obj.try_iter()
        .map_err(|_| PyTypeError::new_err(format!("{}: expected a sequence of str", what())))?
        .map(|x| x?.extract::<String>().map_err(|_| PyTypeError::new_err(format!("{}: expected str items", what()))))
        .collect()
}

/// A required key of an annotation dict.
pub fn item<'py>(d: &Bound<'py, PyDict>, key: &str, what: &dyn Fn() -> String) -> PyResult<Bound<'py, PyAny>> {
    d.get_item(key)?.ok_or_else(|| pyo3::exceptions::PyKeyError::new_err(format!("{}: no key '{key}'", what())))
}

/// `data` as an `(len / cols, cols)` array owning the vector (no copy).
pub fn matrix<'py, T: numpy::Element>(py: Python<'py>, data: Vec<T>, cols: usize) -> PyResult<Bound<'py, PyAny>> {
    let n = data.len().checked_div(cols).unwrap_or(0);
    Ok(data.into_pyarray(py).reshape([n, cols])?.into_any())
}

/// `names` as a numpy array of str (what OpenPCDet's dicts hold).
pub fn str_array<'py>(py: Python<'py>, names: Vec<String>) -> PyResult<Bound<'py, PyAny>> {
    let np = py.import("numpy")?;
    if names.is_empty() {
        return np.call_method1("zeros", (0, "<U1"));
    }
    np.call_method1("array", (names,))
}
