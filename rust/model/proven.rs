//! The straight motions a model has proven free, remembered so that no call proves one twice
//! (a planned path's segments, crossed again by its timing). A leaf of the model layer: it knows
//! only the motions' numbers; the planning layer proves them and writes them here.

/// Straight motions a model has proven free: `a → a + Δ`, states wrapped on continuous hinges
/// (`planning::motion`'s certificate of a straight motion), by the bits of `a` and `Δ`, with
/// the largest clearance each was proven at. `plan_path` writes its returned segments, `time_path` the whole segments it proves;
/// `time_path` reads them, and a part of its timed motion on a segment written here is not proven
/// again: its poses are among the segment's, each certified free, at a clearance at least the
/// one asked, by the certificate itself on this model. A cache of proofs, never of guesses, and
/// bounded: emptied when it holds [`PROVEN_LINES`] motions.
#[derive(Debug, Default)]
pub(crate) struct ProvenLines(std::sync::Mutex<std::collections::HashMap<Vec<u64>, f64>>);

/// Most motions a model's `ProvenLines` holds.
pub(crate) const PROVEN_LINES: usize = 1 << 14;

impl ProvenLines {
    fn key(a: &[f64], delta: &[f64]) -> Vec<u64> {
        a.iter().chain(delta).map(|x| x.to_bits()).collect()
    }

    /// The record, unless another thread holds it: then None, and the caller proves (or does
    /// not write down) the motion, which is always correct. Never waiting also means a child
    /// forked while another thread held the lock (which stays locked there) never hangs on it.
    fn try_lock(&self) -> Option<std::sync::MutexGuard<'_, std::collections::HashMap<Vec<u64>, f64>>> {
        match self.0.try_lock() {
            Ok(map) => Some(map),
            Err(std::sync::TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        }
    }

    /// Writes down that `a → a + delta` was certified at `clearance` metres.
    pub(crate) fn insert(&self, a: &[f64], delta: &[f64], clearance: f64) {
        let Some(mut map) = self.try_lock() else {
            return;
        };
        if map.len() >= PROVEN_LINES {
            map.clear();
        }
        let c = map.entry(Self::key(a, delta)).or_insert(clearance);
        *c = c.max(clearance);
    }

    /// Whether `a → a + delta` was certified at `clearance` metres or more.
    pub(crate) fn holds(&self, a: &[f64], delta: &[f64], clearance: f64) -> bool {
        self.try_lock().is_some_and(|map| map.get(&Self::key(a, delta)).is_some_and(|&c| c >= clearance))
    }

    /// How many motions it holds.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.0.lock().unwrap().len()
    }
}
