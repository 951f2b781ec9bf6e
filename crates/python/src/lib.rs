//! Python bindings of pi3det's libtorch-free crates: the module `pi3det._native` behind the
//! `pi3det` Python package (`python/pi3det/`), an abi3 wheel for CPython ≥ 3.9.
//!
//! * `pi3det.eval`: the KITTI-protocol evaluator (`pi3det-eval`) with OpenPCDet's
//!   `get_official_eval_result` signature and return values, and a variant on LiDAR-frame boxes;
//! * `pi3det.data`: every dataset `pi3det_sequence::open` reads, as a lazy sequence of frames
//!   whose points are handed to numpy without a copy;
//! * `pi3det.geometry`: exact rotated BEV / 3-D IoU matrices and OpenPCDet's rotated NMS;
//! * `pi3det.sim`: the multi-platform simulator, frame by frame.
//!
//! Build and install into the repository's `.venv`: `scripts/setup-python-wheel` (maturin; by
//! hand: `maturin develop -m crates/python/Cargo.toml`). Without the `python` feature — as in
//! `cargo test --workspace` — the crate is empty, so the workspace needs neither pyo3 nor libpython.

#[cfg(feature = "python")]
mod arrays;
#[cfg(feature = "python")]
mod data;
#[cfg(feature = "python")]
mod error;
#[cfg(feature = "python")]
mod eval;
#[cfg(feature = "python")]
mod geometry;
#[cfg(feature = "python")]
mod sim;

#[cfg(feature = "python")]
use pyo3::prelude::*;

/// The extension module; `python/pi3det/*.py` re-export its functions by topic.
#[cfg(feature = "python")]
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Pi3detError", py.get_type::<error::Pi3detError>())?;
    m.add_class::<data::Frame>()?;
    m.add_class::<data::Dataset>()?;
    m.add_class::<sim::Simulation>()?;
    m.add_function(wrap_pyfunction!(eval::kitti_eval, m)?)?;
    m.add_function(wrap_pyfunction!(eval::kitti_eval_detail, m)?)?;
    m.add_function(wrap_pyfunction!(eval::kitti_eval_lidar, m)?)?;
    m.add_function(wrap_pyfunction!(data::open, m)?)?;
    m.add_function(wrap_pyfunction!(geometry::rotated_iou_bev, m)?)?;
    m.add_function(wrap_pyfunction!(geometry::iou_3d, m)?)?;
    m.add_function(wrap_pyfunction!(geometry::nms, m)?)?;
    m.add_function(wrap_pyfunction!(sim::simulate, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
