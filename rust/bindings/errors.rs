//! The error classes of `profrobot._core` and the core's [`Error`] mapped onto them.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

use crate::error::Error;

create_exception!(
    profrobot._core,
    ProfrobotError,
    PyException,
    "Root of every error profrobot raises on purpose (profrobot.errors lists the family)."
);

// The error classes with two bases (ours and Python's own: bad input stays a ValueError, a wrong
// dtype a TypeError). `create_exception!` takes one base, so they are made once, at import, with
// `type(name, bases, namespace)`, and kept here for the raising code.
pub(super) static INPUT_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
pub(super) static INPUT_TYPE_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
pub(super) static MODEL_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// Makes the class `name(*bases)`, adds it to the module `m` and keeps it in `cell`.
pub(super) fn add_error_class<'py>(
    m: &Bound<'py, PyModule>,
    cell: &PyOnceLock<Py<PyType>>,
    name: &str,
    bases: Vec<Bound<'py, PyType>>,
    doc: &str,
) -> PyResult<Bound<'py, PyType>> {
    let py = m.py();
    let ns = PyDict::new(py);
    ns.set_item("__module__", "profrobot._core")?;
    ns.set_item("__doc__", doc)?;
    let bases = PyTuple::new(py, bases)?;
    let class = py.get_type::<PyType>().call1((name, bases, ns))?.cast_into::<PyType>()?;
    m.add(name, &class)?;
    let _ = cell.set(py, class.clone().unbind());
    Ok(class)
}

fn raise(cell: &PyOnceLock<Py<PyType>>, msg: String) -> PyErr {
    Python::attach(|py| match cell.get(py) {
        Some(t) => PyErr::from_type(t.bind(py).clone(), msg),
        None => ProfrobotError::new_err(msg), // not reached: the module's init fills the cells
    })
}

/// Bad input (a shape, a NaN, an option): `profrobot.errors.InputError`, a ValueError.
pub(super) fn input_error(msg: impl Into<String>) -> PyErr {
    raise(&INPUT_ERROR, msg.into())
}

/// A wrong type or dtype: `profrobot.errors.InputTypeError`, a TypeError.
pub(super) fn type_error(msg: impl Into<String>) -> PyErr {
    raise(&INPUT_TYPE_ERROR, msg.into())
}

/// A model the core cannot label exactly: `profrobot.errors.ModelError`, an InputError.
pub(super) fn model_error(msg: impl Into<String>) -> PyErr {
    raise(&MODEL_ERROR, msg.into())
}

pub(super) fn to_py(e: Error) -> PyErr {
    match e {
        // A pair the narrow phase cannot decide (`collision/collide.rs`): the model cannot be labelled
        // exactly; never a label.
        Error::InvalidModel(_) | Error::Undecided(_) => model_error(e.to_string()),
        Error::InvalidInput(_) => input_error(e.to_string()),
        // a loop stopped by a stop another call asked for (`bindings::interrupt`): Ctrl-C
        Error::Interrupted => pyo3::exceptions::PyKeyboardInterrupt::new_err("interrupted"),
    }
}
