//! Thread pools: one rayon pool per thread count, built on first use and reused by every call,
//! and forgotten in a forked child; and the crew (`crew`), helper threads for the few-item
//! sections of calls that run on their own thread ([`on_caller`]).
//!
//! Results never depend on the pool: work is split into fixed-size, independently seeded items.
//!
//! # Fork
//! `fork()` copies only the calling thread. A child of a process that has used a pool (a torch
//! `DataLoader` worker forked after the parent labelled poses) inherits the pool's bookkeeping
//! but none of its threads, and work queued on it would wait forever. The cache records the
//! process id it was built in; a process that finds another id is a forked child, and forgets
//! the inherited pools without dropping them (dropping would signal threads that do not exist
//! there) before building its own. This is tokenizers' `pthread_atfork` habit, checked lazily.
//! Only the pool handles leak in the child, once.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use rayon::prelude::*;
use rayon::{ThreadPool, ThreadPoolBuilder};

use crate::error::{invalid_input, Result};

pub(crate) mod crew;
pub use crew::{awake as crew_awake, awake_for as crew_awake_for, Awake};

/// The pools of one process, by thread count.
struct Pools {
    pid: u32,
    by_threads: HashMap<usize, Arc<ThreadPool>>,
}

/// The pools of the process that built them (see the module docs).
struct PoolCache(Mutex<Option<Pools>>);

static POOLS: PoolCache = PoolCache(Mutex::new(None));

/// The thread count `threads = None` stands for: the cores this process may run on, read once
/// (`available_parallelism` reads the cgroup's quota and the affinity mask, ~0.1 ms a call on a
/// container, which every native call with `threads = None` paid; rayon reads it once too). A
/// forked child keeps its parent's count, also where it changes its affinity.
pub fn default_threads() -> usize {
    static CORES: OnceLock<usize> = OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1))
}

impl PoolCache {
    /// The pools of process `pid`, after forgetting those of any other process: a forked
    /// child's inherited pools have no threads, and dropping them would signal threads that
    /// do not exist.
    fn of_process(slot: &mut Option<Pools>, pid: u32) -> &mut HashMap<usize, Arc<ThreadPool>> {
        let pools = slot.get_or_insert_with(|| Pools { pid, by_threads: HashMap::new() });
        if pools.pid != pid {
            std::mem::forget(std::mem::take(&mut pools.by_threads));
            pools.pid = pid;
        }
        &mut pools.by_threads
    }

    /// The pool of `n` threads of process `pid`, built on first use.
    fn get(&self, pid: u32, n: usize) -> Result<Arc<ThreadPool>> {
        let lock = || self.0.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(p) = Self::of_process(&mut lock(), pid).get(&n) {
            return Ok(p.clone());
        }
        // Built outside the lock, which is only ever held for a lookup: a fork while another
        // thread builds a pool cannot leave the child's lock taken.
        let table = Arc::new(Workers::new(n));
        let built = match ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(|i| format!("profrobot-{i}"))
            .start_handler(move |i| table.started(i))
            .build()
        {
            Ok(p) => Arc::new(p),
            Err(e) => return invalid_input(format!("could not start {n} threads: {e}")),
        };
        // Another thread may have built one meanwhile: keep the first (ours is dropped).
        Ok(Self::of_process(&mut lock(), pid).entry(n).or_insert(built).clone())
    }
}

/// One pool's workers as the OS knows them: each worker's thread id (set as it starts), and
/// whether one of them is steering the others now ([`steer_siblings`]).
struct Workers {
    tids: Vec<std::sync::atomic::AtomicI32>,
    steering: std::sync::atomic::AtomicBool,
}

/// Every pool's workers table, in the order the pools were built (a worker finds its own by
/// index: [`SIBLINGS`]).
static TABLES: Mutex<Vec<Arc<Workers>>> = Mutex::new(Vec::new());

thread_local! {
    /// On a pool's worker: its pool's table (`TABLES`, index + 1) in the high half, its own
    /// index in it in the low half; 0 elsewhere. One word: this library's thread-locals sit in
    /// the process's static TLS block (its `STATIC_TLS` flag), whose few spare bytes a library
    /// loaded later (torch's `libgomp`) needs too, so each of them is kept small.
    static SIBLINGS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// The calling worker's pool's table and its own index in it, on a pool's worker.
fn siblings() -> Option<(Arc<Workers>, usize)> {
    let at = SIBLINGS.get();
    let table = (at >> 32).checked_sub(1)? as usize;
    let w = TABLES.lock().unwrap_or_else(PoisonError::into_inner).get(table)?.clone();
    Some((w, (at & 0xffff_ffff) as usize))
}

impl Workers {
    fn new(n: usize) -> Self {
        Workers { tids: (0..n).map(|_| std::sync::atomic::AtomicI32::new(0)).collect(), steering: false.into() }
    }

    /// Worker `i` has started on the calling thread.
    fn started(self: &Arc<Self>, i: usize) {
        self.tids[i].store(os::thread_id(), std::sync::atomic::Ordering::Release);
        let mut tables = TABLES.lock().unwrap_or_else(PoisonError::into_inner);
        let table = match tables.iter().position(|t| Arc::ptr_eq(t, self)) {
            Some(t) => t,
            None => {
                tables.push(self.clone());
                tables.len() - 1
            }
        };
        SIBLINGS.set((table as u64 + 1) << 32 | i as u64);
    }
}

/// Pools of more workers are not steered: one call per sibling each way, a few µs each, would
/// cost as much as the late start it avoids (the case it was measured on is a 2-core VM).
pub(crate) const STEER_UP_TO: usize = 8;

/// While alive, the calling worker's siblings may not run on the CPU the caller was on
/// ([`steer_siblings`]); dropped, each has the CPUs it had before again.
#[must_use]
pub(crate) struct Steer(Option<Steered>);

/// What a steer changed: the pool, and each steered sibling's thread id with its CPUs before.
pub(crate) struct Steered {
    workers: Arc<Workers>,
    saved: Saved,
}

impl Drop for Steer {
    fn drop(&mut self) {
        if let Some(st) = &self.0 {
            steer_back(&st.saved);
            st.workers.steering.store(false, std::sync::atomic::Ordering::Release);
        }
    }
}

/// Keeps the calling worker's sleeping siblings off its CPU while it hands them work (held over
/// one parallel section). On the 2-core VMs these benchmarks run on, a rayon worker woken for a
/// job that a busy sibling pushed did not start within 600 µs in 110-120 of 200 hand-offs (a
/// plain thread woken by a condition variable: 4 µs at the median), as if placed on the busy
/// CPU: a planned path's segments were all proven on one thread, the second core idle. Steered,
/// the sibling started on the other CPU in 200 of 200 hand-offs, 30-50 µs at the median.
///
/// Placement only, and only for the section: nothing computed depends on it, and each sibling
/// gets back the CPUs it had (pinning each worker to one CPU for good did as well alone, but a
/// pinned thread is never moved off a CPU another process keeps busy). One steer at a time per
/// pool (another caller's section, or one nested in this, leaves placement alone), and a caller
/// outside a profrobot pool, a pool of more than [`STEER_UP_TO`] workers, a sibling whose CPUs
/// cannot be read or would be none, or another OS than Linux leave placement alone.
pub(crate) fn steer_siblings() -> Steer {
    use std::sync::atomic::Ordering;

    let Some((w, me)) = siblings() else {
        return Steer(None);
    };
    if w.tids.len() < 2 || w.tids.len() > STEER_UP_TO {
        return Steer(None);
    }
    let Some(cpu) = os::current_cpu() else {
        return Steer(None);
    };
    if w.steering.swap(true, Ordering::AcqRel) {
        return Steer(None);
    }
    let saved = steer_off(cpu, w.tids.iter().enumerate().filter(|&(i, _)| i != me).map(|(_, tid)| tid.load(Ordering::Acquire)));
    Steer(Some(Steered { workers: w, saved }))
}

/// Threads kept off one CPU: each one's id with the CPUs it had before.
pub(crate) type Saved = Vec<(i32, Vec<usize>)>;

/// Keeps each thread of `tids` off CPU `cpu` where it has another to run on; what it changed.
fn steer_off(cpu: usize, tids: impl Iterator<Item = i32>) -> Saved {
    let mut saved = Vec::new();
    for tid in tids {
        let Some(cpus) = os::allowed(tid) else { continue };
        let others: Vec<usize> = cpus.iter().copied().filter(|&c| c != cpu).collect();
        if !others.is_empty() && others.len() < cpus.len() {
            os::allow(tid, &others);
            saved.push((tid, cpus));
        }
    }
    saved
}

/// Gives each thread `steer_off` steered its CPUs back.
fn steer_back(saved: &Saved) {
    for (tid, cpus) in saved {
        os::allow(*tid, cpus);
    }
}

/// The scheduler calls `steer_siblings` makes (Linux; elsewhere they do nothing).
#[cfg(target_os = "linux")]
mod os {
    /// The calling thread's id (the `gettid` system call: glibc's wrapper is newer than the
    /// manylinux2014 wheels' glibc 2.17).
    pub fn thread_id() -> i32 {
        // SAFETY: gettid takes no arguments and cannot fail.
        unsafe { libc::syscall(libc::SYS_gettid) as i32 }
    }

    /// The CPU the calling thread runs on.
    pub fn current_cpu() -> Option<usize> {
        // SAFETY: sched_getcpu has no preconditions.
        usize::try_from(unsafe { libc::sched_getcpu() }).ok()
    }

    /// The CPUs thread `tid` may run on (its affinity mask), ascending; None for tid 0 (a worker
    /// not started yet: 0 would name the caller) or where it cannot be read.
    pub fn allowed(tid: i32) -> Option<Vec<usize>> {
        if tid == 0 {
            return None;
        }
        // SAFETY: a zeroed cpu_set_t is an empty set; sched_getaffinity writes at most its size.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            if libc::sched_getaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
                return None;
            }
            Some((0..libc::CPU_SETSIZE as usize).filter(|&c| libc::CPU_ISSET(c, &set)).collect())
        }
    }

    /// Lets thread `tid` run on `cpus` only (CPUs it was allowed; a failure changes nothing).
    pub fn allow(tid: i32, cpus: &[usize]) {
        if tid == 0 {
            return;
        }
        // SAFETY: every CPU is below CPU_SETSIZE (read from a cpu_set_t); the call only sets placement.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            for &c in cpus {
                libc::CPU_SET(c, &mut set);
            }
            libc::sched_setaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &set);
        }
    }
}

#[cfg(not(target_os = "linux"))]
mod os {
    pub fn thread_id() -> i32 {
        0
    }
    pub fn current_cpu() -> Option<usize> {
        None
    }
    pub fn allowed(_tid: i32) -> Option<Vec<usize>> {
        None
    }
    pub fn allow(_tid: i32, _cpus: &[usize]) {}
}

thread_local! {
    /// On a thread running a call itself ([`on_caller`]): the call's thread count.
    static CALLER: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// Runs `f` on the calling thread as if on a pool of `threads` workers: its few-item sections
/// ([`map_shared`]) shared with the crew's helpers, its wide parallel loops ([`in_pool`]) on
/// the pool of `threads` workers. No hand-off to the pool and back: a pool worker asleep
/// starts the job tens of µs late on a VM, and the caller, asleep meanwhile, wakes as late
/// when it ends (0.14-0.27 ms of a 1.6 ms `plan_path` call, p10-p90). `Some(0)` is an error.
pub fn on_caller<T>(threads: Option<usize>, f: impl FnOnce() -> T) -> Result<T> {
    let n = count(threads)?;
    let before = CALLER.replace(n);
    struct Restore(usize);
    impl Drop for Restore {
        fn drop(&mut self) {
            CALLER.set(self.0);
        }
    }
    let _restore = Restore(before);
    Ok(f())
}

/// The thread count the calling thread's work runs on: its call's ([`on_caller`]), or its
/// pool's on a pool worker, or 1 (a thread outside both: a crew helper, or a caller that
/// chose no pool).
pub fn current() -> usize {
    match CALLER.get() {
        0 if rayon::current_thread_index().is_some() => rayon::current_num_threads(),
        0 => 1,
        n => n,
    }
}

/// `f()` where rayon's parallel iterators reach the call's pool: on the pool of [`current`]
/// workers when the calling thread runs a call itself ([`on_caller`]), else here (a pool
/// worker's own pool, or rayon's global pool where no pool was chosen).
pub fn in_pool<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    match CALLER.get() {
        n if n > 0 && rayon::current_thread_index().is_none() => match pool(Some(n)) {
            Ok(p) => p.install(f),
            Err(_) => f(),
        },
        _ => f(),
    }
}

/// Runs `f` on this process's pool of `threads` workers (`None`: [`default_threads`]).
///
/// The pool is built on the first call for a count and reused afterwards; a forked child
/// builds its own. `Some(0)` is an error.
///
/// # Example
/// ```
/// use rayon::prelude::*;
/// let sum = profrobot::with_threads(Some(2), || (0..1000u64).into_par_iter().sum::<u64>()).unwrap();
/// assert_eq!(sum, 499_500);
/// assert_eq!(profrobot::with_threads(Some(2), rayon::current_num_threads).unwrap(), 2);
/// assert!(profrobot::with_threads(Some(0), || ()).is_err());
/// ```
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    Ok(pool(threads)?.install(f))
}

/// Poses per parallel work item of every pose loop (labels, the fast paths, forward kinematics):
/// large enough to amortise scheduling, small enough to balance, and fixed, so the split never
/// depends on the thread count. A batch of at most this many is one item, which
/// [`map_chunks`] and the bindings run on the calling thread.
pub const POSE_CHUNK: usize = 256;

/// `data.par_chunks(size).enumerate().map_init(init, f).collect()` on rayon's current pool, or,
/// where `data` is one chunk (or none), the same on the calling thread without touching rayon:
/// no hand-off to a pool and no sleeping worker woken (20-250 µs on a VM after a pause, most of
/// a one-pose call). The chunks, and so the results, are the same either way.
///
/// # Example
/// ```
/// let sums = profrobot::threads::map_chunks(&[1, 2, 3, 4, 5], 2, || (), |_, (i, c)| (i, c.iter().sum::<i32>()));
/// assert_eq!(sums, vec![(0, 3), (1, 7), (2, 5)]);
/// ```
pub fn map_chunks<T, S, R>(
    data: &[T],
    size: usize,
    init: impl Fn() -> S + Sync + Send,
    f: impl Fn(&mut S, (usize, &[T])) -> R + Sync + Send,
) -> Vec<R>
where
    T: Sync,
    R: Send,
{
    let size = size.max(1);
    if data.len() <= size {
        let mut state = init();
        return data.chunks(size).enumerate().map(|c| f(&mut state, c)).collect();
    }
    let _steered = steer_siblings();
    data.par_chunks(size).enumerate().map_init(init, f).collect()
}

/// `f(state, i)` for each `i < n` on rayon's current pool, in item order, each worker taking
/// the next item from one shared counter as it frees up (one `init()` state per worker, made on
/// its first item), or on the calling thread alone where the pool has one worker or `n` is
/// under `shared_from` (at least 2): for items known to be short, whose sharing would cost a
/// sibling's wake-up and steering, tens of µs, for little.
///
/// For a few items of very unequal cost (a path's two to five segments, 20 µs to 2 ms of proof
/// each), where a parallel iterator's halving does not spread them: the worker that splits
/// runs the cheap first half itself and pops the rest back before a sleeping worker has woken
/// (tens of µs on a VM), so a planned path's segments all ran on one thread. Here every item
/// left when the second worker wakes is open to it. Each result is `f`'s of its item alone
/// wherever it runs (the caller's `f` must not depend on the state's history), so the results
/// do not depend on the thread count.
///
/// # Example
/// ```
/// let squares = profrobot::with_threads(Some(2), || profrobot::threads::map_shared(5, 2, || (), |_, i| i * i)).unwrap();
/// assert_eq!(squares, vec![0, 1, 4, 9, 16]);
/// ```
pub fn map_shared<S, R>(n: usize, shared_from: usize, init: impl Fn() -> S + Sync, f: impl Fn(&mut S, usize) -> R + Sync) -> Vec<R>
where
    R: Send,
{
    use std::sync::atomic::{AtomicUsize, Ordering};

    // (outside a pool, a crew helper's nested section among them, on the calling thread alone)
    let workers = current().min(n);
    if workers <= 1 || n < shared_from {
        let mut state = init();
        return (0..n).map(|i| f(&mut state, i)).collect();
    }
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<R>>> = (0..n).map(|_| Mutex::new(None)).collect();
    let work = || {
        let mut state = None;
        loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            if i >= n {
                break;
            }
            let r = f(state.get_or_insert_with(&init), i);
            *slots[i].lock().unwrap_or_else(PoisonError::into_inner) = Some(r);
        }
    };
    // (the crew, awake between a call's sections; the pool's sleeping workers where another
    // section holds it)
    if !crew::try_run(workers - 1, &work) {
        if rayon::current_thread_index().is_none() {
            // (a caller's own section, the crew held by another: alone)
            work();
        } else {
            let _steered = steer_siblings();
            rayon::scope(|s| {
                for _ in 1..workers {
                    s.spawn(|_| work());
                }
                work();
            });
        }
    }
    slots.into_iter().map(|m| m.into_inner().unwrap_or_else(PoisonError::into_inner).expect("every item ran")).collect()
}

/// This process's pool of `threads` workers (`None`: [`default_threads`]), built on first use;
/// `Some(0)` is an error. [`with_threads`] runs a closure on it.
pub fn pool(threads: Option<usize>) -> Result<Arc<ThreadPool>> {
    POOLS.get(std::process::id(), count(threads)?)
}

/// The thread count `threads` stands for (`None`: [`default_threads`]); `Some(0)` is an error.
pub fn count(threads: Option<usize>) -> Result<usize> {
    match threads {
        None => Ok(default_threads()),
        Some(0) => invalid_input("threads must be at least 1"),
        Some(n) => Ok(n),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_pool_per_thread_count_reused_across_calls() {
        let cache = PoolCache(Mutex::new(None));
        let a = cache.get(7, 3).unwrap();
        assert!(Arc::ptr_eq(&a, &cache.get(7, 3).unwrap()));
        assert!(!Arc::ptr_eq(&a, &cache.get(7, 1).unwrap()));
        assert_eq!(a.install(rayon::current_num_threads), 3);
        // The process-wide cache: the same pool on every call.
        let pid = std::process::id();
        let p = POOLS.get(pid, 2).unwrap();
        assert!(Arc::ptr_eq(&with_threads(Some(2), || POOLS.get(pid, 2).unwrap()).unwrap(), &p));
        assert_eq!(with_threads(Some(2), rayon::current_num_threads).unwrap(), 2);
        assert_eq!(with_threads(None, rayon::current_num_threads).unwrap(), default_threads());
    }

    #[test]
    fn regression_forked_child_does_not_reuse_the_parents_pools() {
        // Pools cached by process 7, then asked for by process 8: a child forked after its
        // parent labelled poses, whose inherited pools have no threads.
        let cache = PoolCache(Mutex::new(None));
        let parent = cache.get(7, 2).unwrap();
        let child = cache.get(8, 2).unwrap();
        assert!(!Arc::ptr_eq(&parent, &child), "the inherited pool was reused");
        assert_eq!(child.install(rayon::current_num_threads), 2);
        assert!(Arc::ptr_eq(&child, &cache.get(8, 2).unwrap()));
        let guard = cache.0.lock().unwrap();
        let pools = guard.as_ref().unwrap();
        assert_eq!((pools.pid, pools.by_threads.len()), (8, 1));
        // (`parent` is still usable here, where its threads do exist; in a real child the
        // cache forgets it, one leaked handle per count, by design.)
    }

    /// Item `i`'s result after `rounds` steps of a linear congruential generator: work that
    /// takes time and cannot be skipped.
    fn busy(i: usize, rounds: usize) -> u64 {
        let mut x = i as u64;
        for _ in 0..rounds {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
        }
        x
    }

    #[test]
    fn shared_items_run_once_each_in_order_on_any_pool() {
        // Items of very unequal cost (the first few slow), a state per worker counting its items.
        let run = |threads: usize| {
            with_threads(Some(threads), || {
                let seen: Vec<std::sync::atomic::AtomicUsize> = (0..9).map(|_| Default::default()).collect();
                let out = map_shared(
                    9,
                    2,
                    || 0usize,
                    |done, i| {
                        *done += 1;
                        seen[i].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        (i, busy(i, if i < 3 { 2_000_000 } else { 10 }), rayon::current_thread_index())
                    },
                );
                assert!(seen.iter().all(|n| n.load(std::sync::atomic::Ordering::Relaxed) == 1), "an item ran twice or never");
                out
            })
            .unwrap()
        };
        let (one, two) = (run(1), run(2));
        assert_eq!(one.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>(), two.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>());
        assert!(one.iter().enumerate().all(|(i, r)| r.0 == i));
        assert!(map_shared(0, 2, || (), |_, i| i).is_empty());
        // under `shared_from`, every item on the calling thread
        let on = with_threads(Some(2), || {
            let me = rayon::current_thread_index();
            map_shared(3, 4, || (), |_, _| rayon::current_thread_index() == me)
        })
        .unwrap();
        assert_eq!(on, vec![true; 3]);
    }

    /// A call run on its own thread counts as its thread count wherever it asks: its few-item
    /// sections are shared with crew helpers (the same results as on one thread, each item
    /// once), its wide loops reach the pool of that many workers; a thread outside any call or
    /// pool counts as one.
    #[test]
    fn a_call_on_its_own_thread_has_its_thread_count() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let caller = std::thread::current().id();
        assert_eq!(std::thread::spawn(current).join().unwrap(), 1);
        assert_eq!(on_caller(Some(3), current).unwrap(), 3);
        assert_eq!(with_threads(Some(2), current).unwrap(), 2);
        assert!(on_caller(Some(0), || ()).is_err());
        assert_eq!(
            on_caller(Some(2), || in_pool(|| (rayon::current_num_threads(), rayon::current_thread_index().is_some()))).unwrap(),
            (2, true)
        );
        // (restored after the call, also nested)
        on_caller(Some(2), || on_caller(Some(1), || assert_eq!(current(), 1)).unwrap()).unwrap();
        assert_eq!(std::thread::spawn(current).join().unwrap(), 1);
        let slow = |i: usize| busy(i, if i < 3 { 3_000_000 } else { 10 });
        let want: Vec<u64> = (0..9).map(slow).collect();
        // (another test's section may hold the crew: then this call's run alone, so try again)
        let mut helped = false;
        let tried = std::time::Instant::now();
        while tried.elapsed().as_secs() < 20 {
            let seen: Vec<AtomicUsize> = (0..9).map(|_| Default::default()).collect();
            let out = on_caller(Some(2), || {
                map_shared(
                    9,
                    2,
                    || (),
                    |_, i| {
                        seen[i].fetch_add(1, Ordering::Relaxed);
                        (slow(i), std::thread::current().id() != caller)
                    },
                )
            })
            .unwrap();
            assert!(seen.iter().all(|n| n.load(Ordering::Relaxed) == 1), "an item ran twice or never");
            assert_eq!(out.iter().map(|r| r.0).collect::<Vec<_>>(), want);
            if out.iter().any(|r| r.1) {
                helped = true;
                break;
            }
        }
        assert!(helped, "no crew helper ever took an item");
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn steered_siblings_leave_the_callers_cpu_and_get_their_cpus_back() {
        // A pool of its own (no other test's section steers its workers), 2 workers.
        let pool = PoolCache(Mutex::new(None)).get(9, 2).unwrap();
        let all = os::allowed(os::thread_id()).unwrap();
        pool.install(|| {
            let (w, me) = siblings().expect("a profrobot pool's worker knows its siblings");
            // (the sibling records its id as it starts: wait for it)
            let waited = std::time::Instant::now();
            let sibling = loop {
                match w.tids[1 - me].load(std::sync::atomic::Ordering::Acquire) {
                    0 if waited.elapsed().as_secs() < 5 => std::thread::yield_now(),
                    tid => break tid,
                }
            };
            assert_ne!(sibling, 0);
            let before = os::allowed(sibling).unwrap();
            {
                let steer = steer_siblings();
                let Steered { saved, .. } = steer.0.as_ref().expect("a worker of a pool of two steers");
                let allowed = os::allowed(sibling).unwrap();
                // (the CPU taken away: the one the caller was on, where it could leave it)
                let taken: Vec<usize> = before.iter().copied().filter(|c| !allowed.contains(c)).collect();
                // (the caller runs on one of the process's CPUs, which are the sibling's too)
                if before.len() >= 2 {
                    assert_eq!(saved, &vec![(sibling, before.clone())]);
                    assert_eq!(taken.len(), 1, "{allowed:?} against {before:?}");
                    assert!(!allowed.is_empty() && allowed.iter().all(|c| before.contains(c)));
                } else {
                    assert!(saved.is_empty());
                    assert_eq!(allowed, before, "a sibling that could not leave the CPU was steered");
                }
                // one steer at a time: a second section leaves placement alone
                assert!(steer_siblings().0.is_none());
            }
            assert_eq!(os::allowed(sibling).unwrap(), before, "the sibling did not get its CPUs back");
            assert_eq!(os::allowed(os::thread_id()).unwrap(), all, "the caller was steered");
            assert!(steer_siblings().0.is_some(), "the steer was not released");
        });
        // Outside a profrobot pool (rayon's global one, or no pool), nothing is steered.
        assert!(steer_siblings().0.is_none());
        assert!(rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap().install(steer_siblings).0.is_none());
    }

    #[test]
    fn zero_threads_is_an_error() {
        assert!(with_threads(Some(0), || ()).is_err());
    }
}
