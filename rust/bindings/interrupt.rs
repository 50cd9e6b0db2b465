//! Long calls that stop on Ctrl-C. Python runs its signal handlers only on the main thread and
//! only between bytecodes, so a native call that holds the calling thread for a minute hears
//! Ctrl-C only when it returns. Two ways around it:
//! - [`run`]: the work runs on the rayon pool, and the calling thread waits for it, checking for
//!   signals every [`POLL`]; for the batches, whose wide loops run on the pool anyway;
//! - [`run_here`]: the work runs on the calling thread ([`threads::on_caller`]), whose own
//!   loops check for signals every [`POLL`] (`cancel::watch`); for the calls of a millisecond or
//!   so (`plan_path`, `time_path`), which spent a tenth of it handing the work to a sleeping
//!   worker and being woken by it.
//!
//! Either way, on a signal the loops are asked to stop (`crate::cancel`), the call waits for them
//! (one item of work), and raises the signal's exception (`KeyboardInterrupt`), returning nothing
//! the work computed.

use std::sync::mpsc::{sync_channel, RecvTimeoutError};

use pyo3::prelude::*;

use super::errors::to_py;
use crate::cancel::{self, POLL};
use crate::error::Result;
use crate::threads::{self, count, pool};

/// Batches of at most this many poses are one work item of every pose loop, milliseconds at
/// most: [`run_batch`] runs them on the calling thread.
const ONE_ITEM: usize = crate::threads::POSE_CHUNK;

/// `work()` over a batch of `poses` poses: as [`run`], except that a batch of one work item runs
/// on the calling thread (the GIL released), where the pose loops run one item without rayon
/// (`threads::map_chunks`): no hand-off to the pool and no sleeping worker woken, 20-250 µs on a
/// VM after a pause, most of a one-pose call. Results never depend on where the work runs;
/// `threads=0` is refused all the same (a count no pool could start is not tried).
pub(super) fn run_batch<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    poses: usize,
    work: impl FnOnce() -> Result<T> + Send,
) -> PyResult<T> {
    if poses > ONE_ITEM {
        return run(py, threads, work);
    }
    count(threads).map_err(to_py)?;
    py.detach(work).map_err(to_py)
}

/// `work()` on the pool of `threads` workers, the GIL released, stopping on Ctrl-C (module docs).
/// What `py.detach(|| with_threads(threads, work))` was, with the core's errors mapped to Python's.
pub(super) fn run<T: Send>(py: Python<'_>, threads: Option<usize>, work: impl FnOnce() -> Result<T> + Send) -> PyResult<T> {
    let pool = pool(threads).map_err(to_py)?;
    let mut out: Option<Result<T>> = None;
    let mut signal: Option<PyErr> = None;
    py.detach(|| {
        let (done, finished) = sync_channel::<()>(1);
        let slot = &mut out;
        pool.in_place_scope(|s| {
            s.spawn(move |_| {
                *slot = Some(work());
                let _ = done.send(());
            });
            loop {
                match finished.recv_timeout(POLL) {
                    Ok(()) | Err(RecvTimeoutError::Disconnected) => break,
                    Err(RecvTimeoutError::Timeout) if signal.is_none() => {
                        if let Err(e) = Python::attach(|py| py.check_signals()) {
                            cancel::request();
                            signal = Some(e);
                        }
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                }
            }
        });
    });
    if let Some(e) = signal {
        cancel::clear();
        return Err(e);
    }
    // the job always runs (in_place_scope waits for it); a panic in it propagated above
    out.expect("the interruptible job ran").map_err(to_py)
}

/// The signals' exceptions watched calls' threads raised in their loops ([`run_here`]), by
/// thread. (Not a thread-local: this library's sit in the process's static TLS block, whose
/// spare bytes other libraries need too; see `threads`.)
static SIGNALS: std::sync::Mutex<Vec<(std::thread::ThreadId, PyErr)>> = std::sync::Mutex::new(Vec::new());

/// The calling thread's exception in [`SIGNALS`], taken out.
fn take_signal() -> Option<PyErr> {
    let me = std::thread::current().id();
    let mut all = SIGNALS.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let at = all.iter().position(|(t, _)| *t == me)?;
    Some(all.swap_remove(at).1)
}

/// `work()` on the calling thread as on the pool of `threads` workers ([`threads::on_caller`]),
/// the GIL released, stopping on Ctrl-C: its loops run Python's signal handlers every [`POLL`]
/// (module docs). For calls whose parallel sections are few and short.
pub(super) fn run_here<T: Send>(py: Python<'_>, threads: Option<usize>, work: impl FnOnce() -> Result<T> + Send) -> PyResult<T> {
    let out = py.detach(|| {
        let _watch = cancel::watch(signalled);
        threads::on_caller(threads, work)
    });
    if let Some(e) = take_signal() {
        cancel::clear();
        return Err(e);
    }
    out.and_then(|r| r).map_err(to_py)
}

/// Python's signal handlers run here (the GIL taken for them): `true`, the exception kept for
/// [`run_here`], when one raised. An interpreter shutting down is not attached to (a thread
/// taking its GIL then would be ended by unwinding through the work): no signal.
fn signalled() -> bool {
    Python::try_attach(|py| match py.check_signals() {
        Ok(()) => false,
        Err(e) => {
            let me = std::thread::current().id();
            SIGNALS.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push((me, e));
            true
        }
    })
    .unwrap_or(false)
}
