//! Joint-space functions: SO(2) interpolation and the one-pass check of caller poses.

use numpy::{PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray1, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::arrays::{pose_array, rows_of};
use super::errors::{input_error, to_py, type_error};
use crate::joints::interpolate::interpolate_so2;

/// `(B, steps, K)` interpolation of `(B, K)` start/goal poses (see `_core.pyi`).
#[pyfunction]
pub(super) fn interpolate<'py>(
    py: Python<'py>,
    start: &Bound<'py, PyAny>,
    goal: &Bound<'py, PyAny>,
    steps: usize,
    continuous: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let continuous: PyReadonlyArray1<'py, bool> =
        continuous.extract().map_err(|_| type_error("continuous must be a 1-D bool numpy array of shape (K,)"))?;
    let cont = continuous.as_array().to_vec();
    let k = cont.len();
    let (start, goal) = (pose_array(start, k, "start")?, pose_array(goal, k, "goal")?);
    let (s, g) = (rows_of(&start), rows_of(&goal));
    let b = start.shape()[0];
    let v = py.detach(|| interpolate_so2(&s, &g, steps, &cont)).map_err(to_py)?;
    PyArray1::from_vec(py, v).reshape([b, steps, k])
}

/// `(first non-finite, first outside its column's [lo, hi])` flat indices of `(B, K)` poses, or
/// `None` each (`validate::first_bad_entries`; see `_core.pyi`).
#[pyfunction]
pub(super) fn first_bad_entries<'py>(
    py: Python<'py>,
    poses: &Bound<'py, PyAny>,
    lo: PyReadonlyArray1<'py, f64>,
    hi: PyReadonlyArray1<'py, f64>,
) -> PyResult<(Option<usize>, Option<usize>)> {
    let (lo, hi) = (lo.as_array().to_vec(), hi.as_array().to_vec());
    if lo.is_empty() || lo.len() != hi.len() {
        return Err(input_error(format!("lo and hi must both have shape (K,) with K >= 1; got {} and {}", lo.len(), hi.len())));
    }
    let poses = pose_array(poses, lo.len(), "poses")?;
    let q = rows_of(&poses);
    Ok(py.detach(|| crate::joints::validate::first_bad_entries(&q, &lo, &hi)))
}
