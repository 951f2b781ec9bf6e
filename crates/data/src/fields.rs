//! Typed access to decoded pickle dictionaries, with errors that name the file, the record and
//! the key — so a malformed info file says where it is malformed.

use std::path::Path;

use crate::error::DataError;
use crate::pickle::{NdArray, Value};

/// Where in a file a record came from, for error messages.
pub(crate) struct Record<'a> {
    pub path: &'a Path,
    pub what: String,
}

impl Record<'_> {
    pub fn err(&self, message: impl std::fmt::Display) -> DataError {
        DataError::invalid(self.path, format!("{}: {message}", self.what))
    }

    pub fn get<'v>(&self, v: &'v Value, key: &str) -> Result<&'v Value, DataError> {
        v.get(key).ok_or_else(|| self.err(format!("missing key '{key}'")))
    }

    pub fn str(&self, v: &Value, key: &str) -> Result<String, DataError> {
        let x = self.get(v, key)?;
        scalar_string(x).ok_or_else(|| self.err(format!("'{key}' should be a string, found {}", x.type_name())))
    }

    pub fn opt_str(&self, v: &Value, key: &str) -> Result<Option<String>, DataError> {
        match v.get(key) {
            None | Some(Value::None) => Ok(None),
            Some(x) => scalar_string(x)
                .map(Some)
                .ok_or_else(|| self.err(format!("'{key}' should be a string, found {}", x.type_name()))),
        }
    }

    pub fn opt_f64(&self, v: &Value, key: &str) -> Result<Option<f64>, DataError> {
        match v.get(key) {
            None | Some(Value::None) => Ok(None),
            Some(x) => x
                .as_f64()
                .map(Some)
                .ok_or_else(|| self.err(format!("'{key}' should be a number, found {}", x.type_name()))),
        }
    }

    /// A numeric matrix of `cols` columns from an array or a list of lists; returns rows.
    pub fn matrix(&self, x: &Value, key: &str, min_cols: usize) -> Result<Vec<Vec<f64>>, DataError> {
        let rows: Vec<Vec<f64>> = match x {
            Value::Array(a) if a.ndim() == 1 && a.is_empty() => Vec::new(),
            Value::Array(a) => a
                .to_f64_rows()
                .ok_or_else(|| self.err(format!("'{key}' should be a 2-D numeric array, found {}", describe(a))))?,
            Value::List(items) | Value::Tuple(items) => items
                .iter()
                .map(|r| numbers(r).ok_or_else(|| self.err(format!("'{key}' rows should be lists of numbers"))))
                .collect::<Result<_, _>>()?,
            other => return Err(self.err(format!("'{key}' should be an array, found {}", other.type_name()))),
        };
        if let Some(r) = rows.iter().find(|r| r.len() < min_cols) {
            return Err(self.err(format!("'{key}' rows need at least {min_cols} values, found {}", r.len())));
        }
        Ok(rows)
    }

    /// A 1-D list of strings from a numpy string/object array or a list.
    pub fn strings(&self, x: &Value, key: &str) -> Result<Vec<String>, DataError> {
        match x {
            // OpenPCDet writes empty frames' names as `np.zeros(0)` (a float array).
            Value::Array(a) if a.is_empty() => Ok(Vec::new()),
            Value::Array(a) => {
                a.to_strings().ok_or_else(|| self.err(format!("'{key}' should hold strings, found {}", describe(a))))
            }
            Value::List(items) | Value::Tuple(items) => items
                .iter()
                .map(|s| scalar_string(s).ok_or_else(|| self.err(format!("'{key}' should hold strings"))))
                .collect(),
            other => Err(self.err(format!("'{key}' should be a string array, found {}", other.type_name()))),
        }
    }

    /// A square `N×N` matrix as rows.
    pub fn square<const N: usize>(&self, x: &Value, key: &str) -> Result<[[f64; N]; N], DataError> {
        let rows = self.matrix(x, key, N)?;
        if rows.len() != N || rows.iter().any(|r| r.len() != N) {
            return Err(self.err(format!("'{key}' should be {N}x{N}")));
        }
        Ok(std::array::from_fn(|i| std::array::from_fn(|j| rows[i][j])))
    }
}

/// Strings, and integers written where a string id is expected (`frame_id` as int).
fn scalar_string(v: &Value) -> Option<String> {
    match v {
        Value::Str(s) => Some(s.clone()),
        Value::Int(i) => Some(i.to_string()),
        Value::Bytes(b) => String::from_utf8(b.clone()).ok(),
        _ => None,
    }
}

fn numbers(v: &Value) -> Option<Vec<f64>> {
    match v {
        Value::Array(a) => a.to_f64_vec(),
        Value::List(items) | Value::Tuple(items) => items.iter().map(Value::as_f64).collect(),
        _ => None,
    }
}

fn describe(a: &NdArray) -> String {
    format!("{} array of shape {:?}", a.dtype_name(), a.shape())
}
