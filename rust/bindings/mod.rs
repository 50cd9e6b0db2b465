//! The only folder that knows Python: pyo3 bindings over the core, one file per concern. Heavy
//! calls release the GIL. Documented for users in `python/profrobot/_core.pyi`.

mod arrays;
mod clouds;
mod errors;
mod images;
mod interrupt;
mod joints;
mod model;
mod render;
mod threads;

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

use errors::{add_error_class, ProfrobotError, INPUT_ERROR, INPUT_TYPE_ERROR, MODEL_ERROR};

/// The extension's Rust allocations go through mimalloc (the interpreter's and numpy's do not):
/// freed blocks stay with the process for [`PURGE_DELAY_MS`] and the next call reuses them, where
/// glibc gives large blocks back to the OS at once and faults their pages in again on the next
/// call (measured: 26 000 page faults per render of 40 views, against 2 000-5 000).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc 3's `mi_option_purge_delay` (its `mimalloc.h` enum; the sys crate's table predates it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Milliseconds freed memory stays committed before mimalloc gives it back to the OS. mimalloc's
/// 1 s counts from the first free of a region, so a stream of render calls (a pose fit: one
/// forward and backward every 20 ms-2 s) had its regions purged and faulted in again every
/// second: at 256 views a call, 2.4 ms of system time per view and 3.5 GiB purged in 17 calls;
/// 10 s: 0.7 ms and a per-view cost below a single pose's. The memory a large batch used (1.5 GiB
/// at 256 views) is held 10 s after its last use. `MIMALLOC_PURGE_DELAY` still overrides it.
const PURGE_DELAY_MS: std::os::raw::c_long = 10_000;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one integer option of this library's own allocator (thread-safe in
        // mimalloc; an option read concurrently sees the old or the new value).
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, PURGE_DELAY_MS) };
    }
    m.add_class::<model::PyRobotModel>()?;
    let py = m.py();
    let root = py.get_type::<ProfrobotError>();
    m.add("ProfrobotError", &root)?;
    let input = add_error_class(
        m,
        &INPUT_ERROR,
        "InputError",
        vec![root.clone(), py.get_type::<PyValueError>()],
        "Bad input: a shape, a NaN, an option out of range (a ValueError).",
    )?;
    add_error_class(
        m,
        &MODEL_ERROR,
        "ModelError",
        vec![input],
        "A robot model the core cannot label exactly (inconsistent arrays, unsupported geoms or joints).",
    )?;
    add_error_class(
        m,
        &INPUT_TYPE_ERROR,
        "InputTypeError",
        vec![root, py.get_type::<PyTypeError>()],
        "An argument of the wrong type or dtype (a TypeError).",
    )?;
    m.add_class::<render::PyRenderState>()?;
    m.add_function(wrap_pyfunction!(joints::interpolate, m)?)?;
    m.add_function(wrap_pyfunction!(joints::first_bad_entries, m)?)?;
    m.add_class::<threads::PyCrewAwake>()?;
    m.add_function(wrap_pyfunction!(threads::crew_awake, m)?)?;
    m.add_function(wrap_pyfunction!(clouds::voxel_downsample, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_forward, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_backward, m)?)?;
    m.add_function(wrap_pyfunction!(images::finish_images, m)?)?;
    m.add_function(wrap_pyfunction!(images::finish_images_backward, m)?)?;
    m.add_function(wrap_pyfunction!(images::image_loss, m)?)?;
    m.add_function(wrap_pyfunction!(images::image_loss_backward, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
