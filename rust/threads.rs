//! Thread pools: one rayon pool per thread count, built on first use and reused by every call,
//! and forgotten in a forked child.
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
        let built = match ThreadPoolBuilder::new().num_threads(n).thread_name(|i| format!("profrobot-{i}")).build() {
            Ok(p) => Arc::new(p),
            Err(e) => return invalid_input(format!("could not start {n} threads: {e}")),
        };
        // Another thread may have built one meanwhile: keep the first (ours is dropped).
        Ok(Self::of_process(&mut lock(), pid).entry(n).or_insert(built).clone())
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
    data.par_chunks(size).enumerate().map_init(init, f).collect()
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

    #[test]
    fn zero_threads_is_an_error() {
        assert!(with_threads(Some(0), || ()).is_err());
    }
}
