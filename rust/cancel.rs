//! Cancellation: one process-wide flag the long loops read between items of work, so that a
//! call can be stopped (Ctrl-C in Python) without waiting for it to finish.
//!
//! Who sets it: `bindings::interrupt`. Where the work runs on the pool, the calling thread waits
//! for it and checks for signals while it does; where the work runs on the calling thread
//! itself (short calls: `plan_path`, `time_path`), that thread's own loops ask for the signals
//! at most every [`POLL`] ([`watch`]). On a signal it sets the flag, waits for the loops to
//! notice (one item: a chunk of 256 poses, one IK target, one motion, one planner iteration),
//! clears it and raises `KeyboardInterrupt`. Who reads it: `label_batch`, the fast path's
//! batches, `certify_motions`, `time_path`'s motions, `nearest_free`, `ik` and the planner's
//! budget. A loop that sees it stops with [`Error::Interrupted`], or (the planner) as if its
//! time had run out; either way nothing it computed is returned.
//!
//! The flag is one relaxed atomic load per item: no measurable cost (instructions per pose of
//! `examples/profile_labelling` unchanged); while a call is watched, a check also reads a
//! thread-local and the clock (tens of ns, out of line). It is process-wide on purpose, as
//! SIGINT is: a call running in another thread at that moment stops too, and raises
//! `KeyboardInterrupt` as well.

use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use crate::error::{Error, Result};

/// Bit 0: a stop is asked for. The rest: twice the number of calls watched on their own thread
/// ([`watch`]). Zero, the usual case, costs a loop's check one relaxed load.
static STATE: AtomicUsize = AtomicUsize::new(0);

/// Asks every running loop to stop at its next item.
pub fn request() {
    STATE.fetch_or(1, Ordering::Relaxed);
}

/// Withdraws the request (after the interrupted work has returned): the next call runs whole.
pub fn clear() {
    STATE.fetch_and(!1, Ordering::Relaxed);
}

/// Whether a stop has been asked for; on a thread that runs a watched call ([`watch`]), also
/// whether its watcher, asked at most every [`POLL`], asks for one now.
#[inline]
pub fn requested() -> bool {
    let s = STATE.load(Ordering::Relaxed);
    s != 0 && (s & 1 != 0 || watched_stop())
}

/// How often a watched call's thread asks its watcher.
pub const POLL: Duration = Duration::from_millis(20);

/// The watcher of watched calls ([`watch`]): one a process (the bindings').
static STOPPER: std::sync::Mutex<Option<fn() -> bool>> = std::sync::Mutex::new(None);

/// The clock [`WATCHED`] counts from.
static EPOCH: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();

thread_local! {
    /// On a thread running a watched call: when to ask its watcher next, in nanoseconds from
    /// [`EPOCH`] plus one; 0 elsewhere. One word: this library's thread-locals sit in the
    /// process's static TLS block, whose spare bytes other libraries need too (`threads`).
    static WATCHED: Cell<u64> = const { Cell::new(0) };
}

/// [`WATCHED`]'s value for the time `POLL` from now.
fn next_poll() -> u64 {
    (EPOCH.get_or_init(Instant::now).elapsed() + POLL).as_nanos() as u64 + 1
}

/// While alive, the calling thread's own loops ask `stop()` at most every [`POLL`] whether to
/// stop (from their checks, [`requested`] and [`check`]); on `true` a stop is requested for
/// every loop, as by [`request`]. For a call that runs on the thread that must watch for a
/// stop (Python's signal handlers run on its main thread only): the bindings' Ctrl-C, with no
/// second thread to wait for the work. One watcher serves the process: the last one given.
pub fn watch(stop: fn() -> bool) -> Watch {
    *STOPPER.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some(stop);
    let before = WATCHED.replace(next_poll());
    STATE.fetch_add(2, Ordering::Relaxed);
    Watch(before)
}

/// A watched call ([`watch`]); dropped, its thread's loops stop asking.
#[must_use]
pub struct Watch(u64);

impl Drop for Watch {
    fn drop(&mut self) {
        WATCHED.set(self.0);
        STATE.fetch_sub(2, Ordering::Relaxed);
    }
}

/// [`requested`] where some call is watched: this thread's watcher asked, when due.
#[cold]
#[inline(never)]
fn watched_stop() -> bool {
    let next = WATCHED.get();
    if next == 0 || (EPOCH.get_or_init(Instant::now).elapsed().as_nanos() as u64) < next - 1 {
        return false;
    }
    WATCHED.set(next_poll());
    let stop = *STOPPER.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if stop.is_some_and(|stop| stop()) {
        request();
        return true;
    }
    false
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
// child processes instead, to calls run on the pool and to calls run on their own thread.
