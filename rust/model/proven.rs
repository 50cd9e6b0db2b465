//! The straight motions a model has proven free, remembered so that no call proves one twice
//! (a planned path's segments, crossed again by its timing). A leaf of the model layer: it knows
//! only the motions' numbers; the planning layer proves them and writes them here.

/// Straight motions a model has proven free: `a → a + Δ`, states wrapped on continuous hinges
/// (`planning::motion`'s certificate of a straight motion), by the bits of `a`, `Δ` and the
/// clearance of the proof. `plan_path` records the segments of its sampled search's path that
/// its proof certified; `time_path` records a whole segment it proves to cover a part that
/// failed alone, and reads them: a part of its timed motion on a segment recorded at its
/// clearance is not proven again (its poses are among the segment's, certified by the
/// certificate itself on this model). The same timing as proving it again, which certifies
/// it alone or through its segment, but where the planner clamped a state back into a joint's
/// limits (an ulp at a waypoint on the limit). On continuous hinges a timed path's unwrapped
/// waypoints rarely match the planner's wrapped ones: those segments are proven again. A cache
/// of proofs, never of guesses, and bounded: emptied when it holds [`PROVEN_LINES`] motions.
#[derive(Debug, Default)]
pub(crate) struct ProvenLines(std::sync::Mutex<std::collections::HashSet<Vec<u64>>>);

/// Most motions a model's `ProvenLines` holds.
pub(crate) const PROVEN_LINES: usize = 1 << 14;

impl ProvenLines {
    fn key(a: &[f64], delta: &[f64], clearance: f64) -> Vec<u64> {
        a.iter().chain(delta).chain([&clearance]).map(|x| x.to_bits()).collect()
    }

    /// The record, unless another thread holds it: then None, and the caller proves (or does
    /// not write down) the motion, which is always correct. Never waiting also means a child
    /// forked while another thread held the lock (which stays locked there) never hangs on it.
    fn try_lock(&self) -> Option<std::sync::MutexGuard<'_, std::collections::HashSet<Vec<u64>>>> {
        match self.0.try_lock() {
            Ok(map) => Some(map),
            Err(std::sync::TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        }
    }

    /// Records that `a → a + delta` was certified at `clearance` metres.
    pub(crate) fn insert(&self, a: &[f64], delta: &[f64], clearance: f64) {
        let Some(mut map) = self.try_lock() else {
            return;
        };
        if map.len() >= PROVEN_LINES {
            map.clear();
        }
        map.insert(Self::key(a, delta, clearance));
    }

    /// Whether `a → a + delta` was certified at `clearance` metres.
    pub(crate) fn holds(&self, a: &[f64], delta: &[f64], clearance: f64) -> bool {
        self.try_lock().is_some_and(|map| map.contains(&Self::key(a, delta, clearance)))
    }

    /// How many motions it holds.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.0.lock().unwrap().len()
    }
}
