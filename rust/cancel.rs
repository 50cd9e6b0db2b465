//! Cancellation: one process-wide flag the long loops read between items of work, so that a
//! call can be stopped (Ctrl-C in Python) without waiting for it to finish.
//!
//! Who sets it: `bindings::interrupt`, whose calling thread waits for the work and checks for
//! signals while it does; on a signal it sets the flag, waits for the loops to notice (one item:
//! a chunk of 256 poses, one IK target, one motion, one planner iteration), clears it and raises
//! `KeyboardInterrupt`. Who reads it: `label_batch`, the fast path's batches, `certify_motions`,
//! `nearest_free`, `ik` and the planner's budget. A loop that sees it stops with [`Error::Interrupted`], or (the
//! planner) as if its time had run out; either way nothing it computed is returned.
//!
//! The flag is one relaxed atomic load per item: no measurable cost (instructions per pose of
//! `examples/profile_labelling` unchanged). It is process-wide on purpose, as SIGINT is: a call
//! running in another thread at that moment stops too, and raises `KeyboardInterrupt` as well.

use std::sync::atomic::{AtomicBool, Ordering};

use crate::error::{Error, Result};

static REQUESTED: AtomicBool = AtomicBool::new(false);

/// Asks every running loop to stop at its next item.
pub fn request() {
    REQUESTED.store(true, Ordering::Relaxed);
}

/// Withdraws the request (after the interrupted work has returned): the next call runs whole.
pub fn clear() {
    REQUESTED.store(false, Ordering::Relaxed);
}

/// Whether a stop has been asked for.
#[inline]
pub fn requested() -> bool {
    REQUESTED.load(Ordering::Relaxed)
}

/// `Err(Error::Interrupted)` when a stop has been asked for: a loop's `?` between items. The
/// error is built out of line, so that the hot loops' code stays as it was (instructions per
/// pose of `examples/profile_labelling` within noise of the build without the check).
#[inline(always)]
pub fn check() -> Result<()> {
    if requested() {
        return interrupted();
    }
    Ok(())
}

#[cold]
#[inline(never)]
fn interrupted() -> Result<()> {
    Err(Error::Interrupted)
}

// No unit test sets the flag: the crate's tests run in parallel threads of one process, and a
// stop asked for in one would stop the others. tests/test_interrupt.py sends real SIGINTs to
// child processes instead.
