//! Pairs that one joint alone moves: the joint values at which each is proven clear, found once
//! per model, so that a motion whose sweep of that joint stays inside them needs no state for
//! the pair (`planning/motion.rs`).
//!
//! Two links on either side of one hinge (a Panda's link 1 and link 2, an xArm's, a finger's
//! phalanges) often sit millimetres apart in every configuration. Along a motion such a pair
//! allows only small steps, and the continuous certificate used to place most of its states
//! for it alone (30 of the 30 states of a median xArm7 motion). But its distance is a function
//! of one joint value `θ`: the only joint below the pair's common ancestor body (`planning/motion.rs`,
//! step 1). So it can be certified over `θ` once, instead of over each motion.
//!
//! # The sweep
//! Over the joint's sampling range, by conservative advancement in `θ`: at a placed `θ₀` the
//! pair's lower bound `d` (`collide::Scratch::pair_lower_bound`, as tight as GJK gets it, less
//! the same rounding slack as the certificate's) proves the pair above `need` for
//! `|θ − θ₀| ≤ (d − need) / R`, `R` the pair's lever for the joint (a bound on how fast its
//! distance changes per unit of `θ` in any configuration). The next state is placed at the end of
//! that span, so consecutive spans join. Where the radius falls below [`MIN_RADIUS`] (contact,
//! or nearly), the current span ends and the sweep steps over by [`BLOCKED_STEP`] until the
//! pair is clear again. Joints other than `θ` stay where the base pose puts them: they move
//! both geoms rigidly together, so the distance does not depend on them.
//!
//! `need` is `max(margin, MAX_CLEARANCE)`, the most any certificate asks of the pair, so a span
//! serves every clearance a motion may be certified at. Spans are a function of the model alone
//! (a fresh scratch, pairs in order), the same on any thread.

use crate::collision::collide::Scratch;
use crate::geometry::shapes::Solid;
use crate::model::broad::{slack_above, MAX_CLEARANCE};
use crate::model::RobotModel;

/// Radians (metres for a slide) of `θ`: a state whose radius is below this ends its span.
pub(crate) const MIN_RADIUS: f64 = 1e-5;
/// Radians (metres): the step over a region where the pair is not proven clear.
pub(crate) const BLOCKED_STEP: f64 = 1e-3;
/// Most states one pair's sweep may place; a sweep cut short keeps the spans it found.
const MAX_STATES: usize = 20_000;

/// Sorted, disjoint intervals `[lo, hi]` of one joint's value over which a pair is proven
/// above its `need`.
pub(crate) type Spans = Vec<[f64; 2]>;

/// The distance a pair's spans prove it above: its margin, or the largest clearance a
/// certificate may ask, whichever is more.
#[inline]
pub(crate) fn span_need(model: &RobotModel, k: usize) -> f64 {
    model.pairs[k].margin.max(MAX_CLEARANCE)
}

/// Whether `spans` hold all of `[lo, hi]`.
#[inline]
pub(crate) fn covers(spans: &[[f64; 2]], lo: f64, hi: f64) -> bool {
    let i = spans.partition_point(|s| s[1] < hi);
    i < spans.len() && spans[i][0] <= lo
}

/// Whether candidate pair `k` has the point cloud: its nearest-ball search gives no bound above
/// a need to prove by, so neither a sweep nor a box (`motion::prove_apart`) proves it.
pub(crate) fn has_cloud(model: &RobotModel, k: usize) -> bool {
    let pair = &model.pairs[k];
    [pair.g1, pair.g2].iter().any(|&g| matches!(model.geoms[g].shape.solid, Solid::Cloud(_)))
}

/// The spans of candidate pair `k`, whose distance depends on joint `j` alone, with lever `lever`
/// (`R` in the module docs). Empty for a pair with the point cloud (its nearest-ball search
/// gives no bound above `need` to advance by), a joint without a bounded sampling range, or a
/// pair the narrow phase cannot measure.
pub(crate) fn clear_spans(model: &RobotModel, k: usize, j: usize, lever: f64, s: &mut Scratch) -> Spans {
    let Ok(ranges) = model.sampling_ranges() else {
        return Vec::new();
    };
    if has_cloud(model, k) || !(lever > 0.0 && lever.is_finite()) {
        return Vec::new();
    }
    let need = span_need(model, k);
    let [lo, hi] = ranges[j];
    // The base pose: every joint at the middle of its range (only joint `j` matters).
    let mut q: Vec<f64> = ranges.iter().map(|r| 0.5 * (r[0] + r[1])).collect();
    // (the pair's remembered axis forgotten: the sweep is a function of the model alone)
    s.forget_axes();
    let mut spans = Vec::new();
    let mut open: Option<f64> = None;
    let mut theta = lo;
    for _ in 0..MAX_STATES {
        q[j] = theta.min(hi);
        // (only what the pair reads, bit for bit `place`'s: `Scratch::place_pairs`)
        s.place_pairs(model, &q, std::iter::once(k));
        let Ok(d) = s.pair_lower_bound(model, k, f64::INFINITY, f64::INFINITY) else {
            return Vec::new();
        };
        let slack = slack_above(d, need);
        let r = if slack > 0.0 { slack / lever } else { 0.0 };
        if r >= MIN_RADIUS {
            open.get_or_insert((q[j] - r).max(lo));
            if q[j] + r >= hi {
                push(&mut spans, [open.take().unwrap_or(lo), hi]);
                break;
            }
            theta = q[j] + r;
        } else {
            // (the previous state's span reached this one: it ends here)
            if let Some(start) = open.take() {
                push(&mut spans, [start, q[j]]);
            }
            if q[j] >= hi {
                break;
            }
            theta = q[j] + BLOCKED_STEP;
        }
    }
    if let Some(start) = open {
        // (cut short: proven up to the last state placed)
        push(&mut spans, [start, q[j]]);
    }
    spans
}

/// Appends `span` to the sorted `spans`, merged with the last one where they meet (a state
/// after a blocked one can prove back past where the blocked one ended the last span).
fn push(spans: &mut Spans, span: [f64; 2]) {
    match spans.last_mut() {
        Some(last) if span[0] <= last[1] => last[1] = last[1].max(span[1]),
        _ => spans.push(span),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::collide::{label_batch, LabelOptions};
    use crate::model::desc::ModelDesc;

    #[test]
    fn covers_needs_one_span_holding_the_whole_interval() {
        let spans = vec![[-1.0, 0.0], [0.5, 2.0]];
        assert!(covers(&spans, -1.0, 0.0));
        assert!(covers(&spans, 0.6, 1.9));
        assert!(!covers(&spans, -0.5, 0.6)); // across the gap
        assert!(!covers(&spans, 1.9, 2.1));
        assert!(!covers(&spans, -1.1, -0.5));
        assert!(!covers(&[], 0.0, 0.0));
    }

    /// The pendulum's bob passes 0.05 m below the floor: its spans hold every angle where the
    /// dense labels have the bob more than 1 mm clear, and no angle where it is within `need`
    /// (labelled distances at 20 000 angles over the range).
    #[test]
    fn spans_hold_only_clear_angles_and_most_of_them() {
        let mut desc = ModelDesc::example_pendulum();
        desc.body_pos[1][2] = 0.45;
        let model = RobotModel::new(desc).unwrap();
        let [lo, hi] = model.sampling_ranges().unwrap()[0];
        let lever = crate::planning::motion::lever_of(&model, 0, 0);
        let spans = clear_spans(&model, 0, 0, lever, &mut Scratch::new(&model));
        assert!(!spans.is_empty() && spans.windows(2).all(|w| w[0][1] < w[1][0]), "{spans:?}");
        let angles: Vec<f64> = (0..=20_000).map(|i| lo + (hi - lo) * i as f64 / 20_000.0).collect();
        let labels = label_batch(&model, &angles, LabelOptions { pairs: false, distance: true }).unwrap();
        let need = span_need(&model, 0);
        for (&a, l) in angles.iter().zip(&labels.labels) {
            let inside = covers(&spans, a, a);
            assert!(!inside || l.min_distance > need, "angle {a}: in a span at distance {}", l.min_distance);
            if l.min_distance > 1e-3 {
                assert!(inside, "angle {a}: {} m clear, in no span {spans:?}", l.min_distance);
            }
        }
    }

    /// On the bundled Panda, xArm7 and UR5e scenes: every pair one joint alone moves gets spans,
    /// and at 300 random values inside them (the other joints random too) the pair is proven
    /// clear by the exact per-pair test the certificates use (`Scratch::clear_of`).
    #[test]
    fn spans_of_the_bundled_arms_hold_only_clear_values() {
        use rand::{Rng, SeedableRng};
        for scene in ["panda_blocks", "xarm7_table", "ur5e_wall_box"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let desc: ModelDesc = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            let model = RobotModel::new(desc).unwrap();
            let ranges = model.sampling_ranges().unwrap();
            let spans = crate::planning::motion::joint_spans(&model);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
            let mut s = Scratch::new(&model);
            let mut checked = 0;
            for (k, (j, sp)) in spans.iter().enumerate().filter(|(_, (j, _))| *j != u32::MAX) {
                assert!(!sp.is_empty(), "{scene}: pair {k} has no span");
                for _ in 0..300 {
                    let mut q: Vec<f64> = ranges.iter().map(|r| rng.random_range(r[0]..=r[1])).collect();
                    let span = sp[rng.random_range(0..sp.len())];
                    q[*j as usize] = rng.random_range(span[0]..=span[1]);
                    s.place(&model, &q, false);
                    assert!(s.clear_of(&model, k, MAX_CLEARANCE).unwrap(), "{scene}: pair {k} at {q:?}");
                    checked += 1;
                }
            }
            assert!(checked >= 900, "{scene}: {checked}");
        }
    }
}
