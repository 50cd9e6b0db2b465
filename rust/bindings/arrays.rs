//! numpy arguments read in any memory layout, shared by every binding.

use std::borrow::Cow;

use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::errors::{input_error, type_error};

/// `obj` as a 2-D float64 array with `k` columns (any memory layout), or a TypeError/ValueError
/// naming `what`, the dtype and the shape it wants.
pub(super) fn pose_array<'py>(obj: &Bound<'py, PyAny>, k: usize, what: &str) -> PyResult<PyReadonlyArray2<'py, f64>> {
    let a: PyReadonlyArray2<'py, f64> = obj.extract().map_err(|_| {
        let dtype = obj.getattr("dtype").and_then(|d| d.str()).map(|d| d.to_string());
        let ndim = obj.getattr("ndim").and_then(|n| n.extract::<usize>());
        let got = match (dtype, ndim) {
            (Ok(d), Ok(n)) => format!("a {n}-D {d} array"),
            _ => format!("a {}", obj.get_type().name().map(|n| n.to_string()).unwrap_or_default()),
        };
        type_error(format!("{what} must be a 2-D float64 numpy array of shape (B, {k}); got {got}"))
    })?;
    let shape = a.shape();
    if shape[1] != k {
        return Err(input_error(format!("{what} must have shape (B, {k}); got {shape:?}")));
    }
    Ok(a)
}

/// The elements of `a` (any dimension) as one row-major buffer: borrowed when `a` is C-contiguous, otherwise copied
/// element by element through its strides (Fortran order, negative strides, sliced views).
///
/// Exactness: rust-numpy's `as_slice` succeeds for *any* contiguous array, Fortran order
/// included, and would hand back the memory in storage order; reading it as rows silently
/// transposes the poses. Only `is_c_contiguous` guarantees storage order == row order.
///
/// A broadcast constant (every stride 0: one element seen everywhere, e.g. the gradient of a
/// plain sum, or zeros for an unused output) is filled at memset speed in this library's
/// allocator instead of being materialised by the caller (75 MB of fresh pages at 256 views).
pub(super) fn rows_of<'a, T: numpy::Element + Copy, D: numpy::ndarray::Dimension>(a: &'a numpy::PyReadonlyArray<'_, T, D>) -> Cow<'a, [T]> {
    if a.is_c_contiguous() {
        if let Ok(s) = a.as_slice() {
            return Cow::Borrowed(s);
        }
    }
    let view = a.as_array();
    if let Some(&first) = view.first() {
        if view.strides().iter().all(|&s| s == 0) {
            return Cow::Owned(vec![first; view.len()]);
        }
    }
    Cow::Owned(view.iter().copied().collect())
}

/// The compute dtype the image functions take from `alpha`: float32, else float64 (any other
/// dtype then fails its read with a TypeError naming what it got).
pub(super) fn dtype_of(obj: &Bound<'_, PyAny>) -> &'static str {
    match obj.getattr("dtype").and_then(|d| d.str()).map(|s| s.to_string()).as_deref() {
        Ok("float32") => "float32",
        _ => "float64",
    }
}
