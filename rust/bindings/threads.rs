//! The threads a call runs on: the crew's helpers woken ahead of it.

use pyo3::prelude::*;

use super::errors::to_py;
use crate::threads::{count, crew_awake_for, Awake};

/// While alive, the crew's helpers stay awake for a call on its thread count (see `_core.pyi`
/// and `threads/crew.rs`); a guard of one call, not pickled.
#[pyclass(name = "CrewAwake", module = "profrobot._core", frozen)]
pub(super) struct PyCrewAwake(#[allow(dead_code)] Awake);

/// The crew woken for a call on `threads` threads, ahead of it (see `_core.pyi`).
#[pyfunction]
#[pyo3(signature = (threads=None))]
pub(super) fn crew_awake(threads: Option<usize>) -> PyResult<PyCrewAwake> {
    Ok(PyCrewAwake(crew_awake_for(count(threads).map_err(to_py)?)))
}
