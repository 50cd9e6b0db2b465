//! The crew: plain helper threads that join a few short parallel sections of one call
//! (`map_shared`), kept awake between them.
//!
//! A rayon worker asleep is slow to wake on the 2-core VMs these benchmarks run on: a job a
//! worker spawned for its sleeping sibling started 54 / 73 / 93 µs later (p10 / p50 / p90 of 300
//! hand-offs after an 80 µs sequential stretch, the sibling steered off the busy CPU), where a
//! plain thread woken by a condition variable started after 2.6 / 6.2 / 8.7 µs. A timed path is
//! two to four such sections of 0.1-0.5 ms each, with 50-100 µs of sequential work between them,
//! so the late starts were a tenth of the call. A crew helper looks for the next section for
//! `SPIN` after each one before it sleeps, and for up to `AWAKE_SPIN` while a call that runs
//! sections holds it awake ([`awake`]): within that call it is awake when a section comes.
//!
//! One section at a time holds the crew (`try_run`); another caller meanwhile (a second
//! Python thread, or a section nested in a section) is told so and runs its section another way.
//! Nothing computed depends on who runs an item: the caller's work hands out items from one
//! counter and each item's result is its own.
//!
//! Fork: `fork()` copies only the calling thread, so a child inherits the crew's bookkeeping and
//! none of its helpers. The crew records the process id it was built in; a process that finds
//! another id forgets it (leaks it: dropping would touch state the helpers may have held locked)
//! and builds its own, as the pools do. The crew's slot is never waited for (`held`): a child
//! forked while another thread held it runs its sections alone.

use std::any::Any;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

/// How long an idle helper keeps looking for the next section before it sleeps, where no call
/// holds it awake: a section that follows at once finds it, and a finished call leaves no core
/// busy for long.
pub(crate) const SPIN: Duration = Duration::from_micros(50);

/// How long a section's caller, its own share done, looks for its helpers' end before it
/// sleeps: their last items (a motion's proof, up to milliseconds), its CPU yielded meanwhile to
/// any thread that needs it. Asleep, it would wake tens of µs after them on a VM.
const WAIT_SPIN: Duration = Duration::from_millis(2);

/// How long a helper kept awake ([`awake`]) looks for the next section before it sleeps all
/// the same: far longer than the sequential work between a call's sections, so that a long
/// stretch of it (or a caller that forgot its guard) leaves no core spinning.
const AWAKE_SPIN: Duration = Duration::from_millis(1);

/// Calls on more threads keep no helper awake ([`awake`]): as many cores spinning, and two
/// system calls a helper to steer them, would cost more than the late starts they avoid.
const AWAKE_UP_TO: usize = super::STEER_UP_TO;

/// A section's work, its lifetime erased: valid while the section that posted it waits
/// (`try_run` returns only once no helper holds it).
#[derive(Clone, Copy)]
struct Job(*const (dyn Fn() + Sync + 'static));

// SAFETY: the closure behind the pointer is `Sync`; the pointer is only dereferenced while the
// section that owns the closure waits for it (module docs).
unsafe impl Send for Job {}

/// What the lock guards.
struct State {
    /// The posted section's work, while seats are open on it.
    job: Option<Job>,
    /// Helpers that may still join the posted section.
    seats: usize,
    /// Helpers asleep on `wake`.
    sleepers: usize,
    /// Whether the caller sleeps on `done`.
    caller_sleeps: bool,
    /// The first panic of a helper in the current section.
    panic: Option<Box<dyn Any + Send>>,
    /// Whether a section holds the crew.
    busy: bool,
    /// The helpers' thread ids, as each starts.
    tids: Vec<i32>,
    /// Whether an [`Awake`] keeps the helpers off its CPU.
    steered: bool,
}

pub(crate) struct Shared {
    state: Mutex<State>,
    /// Sections posted so far: helpers spin on it.
    posted: AtomicU64,
    /// Helpers inside the current section's work.
    running: AtomicUsize,
    /// Live [`Awake`] guards: while above zero, idle helpers do not sleep.
    awake: AtomicUsize,
    wake: Condvar,
    done: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Tells the helpers something was posted (a section, or a call that keeps them awake),
    /// waking those asleep; `st` is the held lock, under which they go to sleep.
    fn post(&self, st: &State) {
        self.posted.fetch_add(1, Ordering::Release);
        if st.sleepers > 0 {
            self.wake.notify_all();
        }
    }
}

/// The helpers of one process.
pub(crate) struct Crew {
    pid: u32,
    shared: Arc<Shared>,
    helpers: usize,
}

/// The crew of the process that built it (module docs), grown to the most helpers asked for.
static CREW: Mutex<Option<Crew>> = Mutex::new(None);

/// `work()` on the calling thread and on `helpers` crew helpers at once, returning when every
/// one of them has returned from it; `false` without running anything when another section
/// holds the crew or a helper could not be started (the caller then runs `work` another way).
/// `work` must be done when the caller's own run of it returns, save for items helpers took
/// (`map_shared`'s shared counter): a helper that wakes after that finds no seat.
pub(crate) fn try_run(helpers: usize, work: &(dyn Fn() + Sync)) -> bool {
    let Some(shared) = take(helpers) else {
        return false;
    };
    // SAFETY: only the lifetime is erased; `section` returns only once no helper holds the job.
    let job = Job(unsafe { std::mem::transmute::<&(dyn Fn() + Sync), &(dyn Fn() + Sync + 'static)>(work) });
    section(&shared, helpers, job, work);
    true
}

/// Keeps the crew's helpers awake, looking for sections, while it lives (they sleep `SPIN`
/// after the last guard is dropped, or `AWAKE_SPIN` after a section while it lives): a call
/// about to run sections takes one first, so that the helpers' wake-up overlaps its sequential
/// work and they do not fall asleep between its sections. An awake helper spins off the
/// caller's CPU (steered, as the pools' sleeping workers are). Where the call runs on one
/// thread, or on more than `AWAKE_UP_TO` (8), or the crew is busy being grown, nothing is woken.
pub fn awake() -> Awake {
    awake_for(super::current())
}

/// [`awake`] for a call about to run on `n` threads, taken before it starts (the bindings'
/// `crew_awake`: the helpers' wake-up then overlaps the Python checks ahead of the call, where
/// [`awake`] inside it gave a timed path's first section a helper 24 µs late).
pub fn awake_for(n: usize) -> Awake {
    if !(2..=AWAKE_UP_TO).contains(&n) {
        return Awake(None);
    }
    let Some(shared) = held().and_then(|mut slot| grown(&mut slot, n - 1)) else {
        return Awake(None);
    };
    // (the helpers kept off the caller's CPU while awake: a helper spinning beside the caller
    // would halve it until the scheduler moved one of them, milliseconds)
    let mut st = shared.lock();
    let mut steered = None;
    if !st.steered {
        if let Some(cpu) = super::os::current_cpu() {
            st.steered = true;
            steered = Some(super::steer_off(cpu, st.tids.iter().copied()));
        }
    }
    shared.awake.fetch_add(1, Ordering::AcqRel);
    shared.post(&st);
    drop(st);
    Awake(Some((shared, steered)))
}

/// While alive, the crew stays awake ([`awake`]).
#[must_use]
pub struct Awake(Option<(Arc<Shared>, Option<super::Saved>)>);

impl Drop for Awake {
    fn drop(&mut self) {
        if let Some((shared, steered)) = &self.0 {
            shared.awake.fetch_sub(1, Ordering::AcqRel);
            if let Some(saved) = steered {
                super::steer_back(saved);
                shared.lock().steered = false;
            }
        }
    }
}

/// The crew with at least `helpers` helpers, held for one section; `None` when another section
/// holds it or a thread could not be started.
fn take(helpers: usize) -> Option<Arc<Shared>> {
    let shared = grown(&mut *held()?, helpers)?;
    let mut st = shared.lock();
    if st.busy {
        return None;
    }
    st.busy = true;
    drop(st);
    Some(shared)
}

/// The crew's slot, or `None` while another thread holds it (growing the crew, or looking it
/// up): the caller then does without it. Never waited for: a child forked while another
/// thread held it inherits it held for good, and runs its sections alone.
fn held() -> Option<MutexGuard<'static, Option<Crew>>> {
    match CREW.try_lock() {
        Ok(g) => Some(g),
        Err(std::sync::TryLockError::Poisoned(p)) => Some(p.into_inner()),
        Err(std::sync::TryLockError::WouldBlock) => None,
    }
}

/// This process's crew (built, or rebuilt in a forked child), grown to at least `helpers`
/// helpers; `None` where a thread could not be started.
fn grown(slot: &mut Option<Crew>, helpers: usize) -> Option<Arc<Shared>> {
    let pid = std::process::id();
    if slot.as_ref().is_some_and(|c| c.pid != pid) {
        std::mem::forget(slot.take());
    }
    let crew = slot.get_or_insert_with(|| Crew {
        pid,
        shared: Arc::new(Shared {
            state: Mutex::new(State {
                job: None,
                seats: 0,
                sleepers: 0,
                caller_sleeps: false,
                panic: None,
                busy: false,
                tids: Vec::new(),
                steered: false,
            }),
            posted: AtomicU64::new(0),
            running: AtomicUsize::new(0),
            awake: AtomicUsize::new(0),
            wake: Condvar::new(),
            done: Condvar::new(),
        }),
        helpers: 0,
    });
    while crew.helpers < helpers {
        let shared = crew.shared.clone();
        // (from the sections posted so far on: the one about to be posted is the helper's first)
        let seen = shared.posted.load(Ordering::Acquire);
        std::thread::Builder::new().name(format!("profrobot-crew-{}", crew.helpers)).spawn(move || helper(&shared, seen)).ok()?;
        crew.helpers += 1;
    }
    Some(crew.shared.clone())
}

/// Posts `job` (the erased `work`) to `helpers` seats, runs `work` here, closes the seats and
/// waits for the helpers that took one; a panic, the caller's or a helper's, goes on from here
/// once none holds the job.
fn section(shared: &Shared, helpers: usize, job: Job, work: &(dyn Fn() + Sync)) {
    {
        let mut st = shared.lock();
        st.job = Some(job);
        st.seats = helpers;
        st.panic = None;
        shared.post(&st);
    }
    let mine = catch_unwind(AssertUnwindSafe(work));
    // (a helper that joins from here on would find the work done: no seat for it)
    let panic = {
        let mut st = shared.lock();
        st.seats = 0;
        st.job = None;
        let spun = Instant::now();
        drop(st);
        while shared.running.load(Ordering::Acquire) > 0 && spun.elapsed() < WAIT_SPIN {
            std::thread::yield_now();
        }
        let mut st = shared.lock();
        while shared.running.load(Ordering::Acquire) > 0 {
            st.caller_sleeps = true;
            st = shared.done.wait(st).unwrap_or_else(PoisonError::into_inner);
        }
        st.caller_sleeps = false;
        st.busy = false;
        st.panic.take()
    };
    if let Err(p) = mine {
        resume_unwind(p);
    }
    if let Some(p) = panic {
        resume_unwind(p);
    }
}

/// A helper's life, from the sections posted after the `seen`-th: wait for a section (spinning
/// for [`SPIN`], or [`AWAKE_SPIN`] while held awake, then asleep), take a seat if one is open,
/// run the work, say so; forever.
fn helper(shared: &Shared, mut seen: u64) {
    shared.lock().tids.push(super::os::thread_id());
    loop {
        let spun = Instant::now();
        while shared.posted.load(Ordering::Acquire) == seen {
            let limit = if shared.awake.load(Ordering::Acquire) > 0 { AWAKE_SPIN } else { SPIN };
            if spun.elapsed() >= limit {
                break;
            }
            for _ in 0..64 {
                std::hint::spin_loop();
            }
        }
        let job = {
            let mut st = shared.lock();
            while shared.posted.load(Ordering::Acquire) == seen {
                st.sleepers += 1;
                st = shared.wake.wait(st).unwrap_or_else(PoisonError::into_inner);
                st.sleepers -= 1;
            }
            seen = shared.posted.load(Ordering::Acquire);
            match st.job {
                Some(job) if st.seats > 0 => {
                    st.seats -= 1;
                    shared.running.fetch_add(1, Ordering::AcqRel);
                    job
                }
                _ => continue,
            }
        };
        // SAFETY: the section that posted the job waits until `running` is back to zero.
        let ran = catch_unwind(AssertUnwindSafe(|| unsafe { (*job.0)() }));
        let mut st = shared.lock();
        if let Err(p) = ran {
            st.panic.get_or_insert(p);
        }
        if shared.running.fetch_sub(1, Ordering::AcqRel) == 1 && st.caller_sleeps {
            shared.done.notify_one();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every helper that takes a seat runs the work, the caller waits for each, and a busy
    /// crew says so instead of running.
    #[test]
    fn sections_wait_for_their_helpers_and_one_holds_the_crew() {
        use std::sync::atomic::AtomicBool;
        for _ in 0..200 {
            let ran = AtomicUsize::new(0);
            let inside = AtomicBool::new(false);
            let nested = AtomicUsize::new(0);
            let work = || {
                ran.fetch_add(1, Ordering::SeqCst);
                if !inside.swap(true, Ordering::SeqCst) {
                    // (a section nested in one that holds the crew is refused)
                    nested.fetch_add(!try_run(1, &|| ()) as usize, Ordering::SeqCst);
                }
                std::thread::sleep(Duration::from_micros(50));
            };
            // (another test may hold the crew: then this one runs nothing, and says so)
            if try_run(1, &work) {
                let n = ran.load(Ordering::SeqCst);
                assert!((1..=2).contains(&n), "{n} runs");
                assert_eq!(nested.load(Ordering::SeqCst), 1);
            } else {
                assert_eq!(ran.load(Ordering::SeqCst), 0);
            }
        }
    }

    /// A helper's panic reaches the caller, once every helper is out; the crew is free after.
    #[test]
    fn a_helpers_panic_reaches_the_caller() {
        let caller = std::thread::current().id();
        let work = || {
            if std::thread::current().id() != caller {
                panic!("helper");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut tries = 0;
        loop {
            tries += 1;
            match catch_unwind(AssertUnwindSafe(|| try_run(1, &work))) {
                Err(p) => {
                    assert_eq!(p.downcast_ref::<&str>(), Some(&"helper"));
                    break;
                }
                Ok(_) => assert!(tries < 100, "no helper ever took a seat"),
            }
        }
    }
}
