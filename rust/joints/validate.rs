//! Checks of caller input done in one pass over large arrays (Python's `as_poses`): numpy's
//! comparisons allocate a temporary array per operator and its column reductions are slow,
//! several milliseconds for a batch of poses that the labeller itself handles in a few tens.

/// For the row-major `(B, K)` `poses` (`K = lo.len() = hi.len()`): the flat index of the first
/// entry that is not finite, and of the first entry outside `[lo[j], hi[j]]` of its column `j`
/// (an unlimited column: `lo = -inf`, `hi = inf`). Both in row-major order, `None` when there is
/// none; one pass (a row is inspected entry by entry only when it holds one of either).
///
/// # Panics
/// When `lo` is empty (K = 0), `lo` and `hi` differ in length, or `poses` is not whole rows of
/// K entries (the caller's shape checks come first).
pub fn first_bad_entries(poses: &[f64], lo: &[f64], hi: &[f64]) -> (Option<usize>, Option<usize>) {
    let k = lo.len();
    assert!(hi.len() == k && k > 0 && poses.len() % k == 0, "poses must be whole rows of K = {k} entries");
    let (mut nonfinite, mut outside) = (None, None);
    for (i, row) in poses.chunks_exact(k).enumerate() {
        // (no early exit within a row: the loop vectorises; `|` not `||`)
        let mut bad = false;
        for j in 0..k {
            let v = row[j];
            bad |= !v.is_finite() | (v < lo[j]) | (v > hi[j]);
        }
        if !bad {
            continue;
        }
        for (j, &v) in row.iter().enumerate() {
            if nonfinite.is_none() && !v.is_finite() {
                nonfinite = Some(i * k + j);
            }
            if outside.is_none() && (v < lo[j] || v > hi[j]) {
                outside = Some(i * k + j);
            }
        }
        if nonfinite.is_some() && outside.is_some() {
            break;
        }
    }
    (nonfinite, outside)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the entry-by-entry definition, on rows with NaN, infinities, entries on, inside and
    /// just outside the bounds, and unlimited columns.
    #[test]
    fn first_bad_entries_are_the_first_in_row_major_order() {
        let (lo, hi) = ([-1.0, f64::NEG_INFINITY, 0.0], [1.0, f64::INFINITY, 2.0]);
        let values = [0.0, -1.0, 1.0, 1.0 + 1e-15, -3.0, 2.0, 5e300, f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
        let mut seed = 7u64;
        for _ in 0..2000 {
            let rows = 1 + (seed % 5) as usize;
            let poses: Vec<f64> = (0..rows * 3)
                .map(|_| {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    let v = values[(seed >> 33) as usize % values.len()];
                    // (mostly fine entries, so that rows without either kind occur)
                    if (seed >> 20) % 3 == 0 {
                        v
                    } else {
                        0.5
                    }
                })
                .collect();
            let want_nonfinite = poses.iter().position(|v| !v.is_finite());
            let want_outside = poses.iter().enumerate().position(|(n, &v)| v < lo[n % 3] || v > hi[n % 3]);
            assert_eq!(first_bad_entries(&poses, &lo, &hi), (want_nonfinite, want_outside), "{poses:?}");
        }
    }
}
