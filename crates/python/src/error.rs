//! The one place where the libraries' `thiserror` errors become Python exceptions: a
//! `pi3det.Pi3detError` carrying the Rust message (file, line, what is wrong) and, where the error
//! names a file, that file as its `path` attribute.

use std::path::Path;

use pi3det_data::DataError;
use pi3det_eval::EvalError;
use pi3det_sim::SimError;
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    pi3det,
    Pi3detError,
    PyException,
    "An error of pi3det's Rust code; `path` is the file it is about (or None)."
);

/// A library error as a `Pi3detError`: the message with its causes (as the `pi3det` binary
/// prints them) and the file it names.
fn raise(error: &(dyn std::error::Error + 'static), path: Option<&Path>) -> PyErr {
    let err = Pi3detError::new_err(pi3det_data::error::report(error));
    Python::attach(|py| {
        let path = path.map(|p| p.display().to_string());
        // Setting an attribute on a fresh exception instance cannot fail in practice; if it did,
        // the message still names the file.
        let _ = err.value(py).setattr("path", path);
    });
    err
}

pub(crate) fn data_path(e: &DataError) -> Option<&Path> {
    match e {
        DataError::Io { path, .. }
        | DataError::Invalid { path, .. }
        | DataError::Line { path, .. }
        | DataError::Pickle { path, .. }
        | DataError::Exists { path }
        | DataError::UnknownFormat { path, .. } => Some(path),
    }
}

pub(crate) fn data(e: DataError) -> PyErr {
    raise(&e, data_path(&e))
}

pub(crate) fn eval(e: EvalError) -> PyErr {
    let path = match &e {
        EvalError::Io { path, .. } | EvalError::Invalid { path, .. } | EvalError::Line { path, .. } => {
            Some(path.as_path())
        }
        EvalError::Data(d) => data_path(d),
        EvalError::Option(_) | EvalError::Input(_) => None,
    };
    raise(&e, path)
}

pub(crate) fn sim(e: SimError) -> PyErr {
    let path = match &e {
        SimError::Data(d) => data_path(d),
        SimError::Io { path, .. } | SimError::Config { path, .. } | SimError::Preview { path, .. } => {
            Some(path.as_path())
        }
        SimError::Invalid(_) => None,
    };
    raise(&e, path)
}
