//! The booleans-only fast path: whether each pose collides, stopping at the first pair in
//! contact, with the likeliest pairs tried first (the last pair hit alone for the planner's
//! states, `First`).
//!
//! # Same answer as `label_pose`
//! `label_pose(..).collides()` is "some candidate pair is in contact", each pair decided by
//! `collide::Scratch::in_contact`, a pure function of the pose; which pairs the broad phase lets
//! through does not change it (`model/broad.rs`: a pair it drops is one the narrow phase would find
//! apart). Here every pair is decided by the same function on the same frames, and "some pair
//! is in contact" does not depend on the order in which pairs are tried, nor on stopping at
//! the first that is; pairs tried early are skipped later (`Scratch::tested`), never decided
//! twice. So the answer is `label_pose`'s, bit for bit, whatever the order.
//!
//! # Order
//! 1. the pair that hit on the previous pose of this thread (nearby poses, as in a bisection
//!    or along a path, tend to hit the same pair);
//! 2. the model's likely pairs (`likely_pairs`): a greedy cover of the colliding poses of a
//!    seeded sample, so that one of the first few pairs tried is in contact in most colliding
//!    poses; each behind its own bounding-sphere test;
//! 3. the rest, through the broad phase.
//!
//! (The planner's states, mostly free, skip step 2: `First::LastHit`, and `first_colliding`.)
//!
//! Free poses cost what `label_pose` costs (every pair must be cleared); colliding poses
//! usually stop after one or two narrow-phase tests.
//!
//! A pair the narrow phase cannot decide is an error here too (`collision/collide.rs`, "never free"):
//! `collides_pose` stops at it, and `collides_batch` fails naming the pose and the pair. (A pose
//! with another pair in contact may stop at that pair first and answer `true`, which is right
//! whatever the undecided pair would say.)

use crate::collision::collide::{first_error, label_pose, LabelOptions, Scratch, Scratch4, Undecided};
use crate::error::Result;
use crate::joints::sample::{fill_block, BLOCK};
use crate::model::broad::check_clearance;
use crate::model::{InheritedLikely, Likely, RobotModel};

/// Poses per parallel work item (`threads::POSE_CHUNK`).
const CHUNK: usize = crate::threads::POSE_CHUNK;

/// Sample behind `likely_pairs`: poses, seed.
const SAMPLE_POSES: usize = 512;
/// Poses of the sample for a model rebuilt from one that had made its proofs (a scene update,
/// `RobotModel::rebuilt`), whose first use should cost milliseconds: labelling 512 poses took
/// 1.3 ms of a MotionBenchMaker Panda's 6 ms first plan, 128 take a quarter of it, and the
/// plans after it were no slower (`benches/mbm.py`'s problems: second calls' median 3.87 ms
/// both ways, the first calls' 0.8 ms lower). The first `SAMPLE_POSES_REBUILT` poses of any
/// sample are these (`fill_block`), so the old model's contacts are taken over as they are.
const SAMPLE_POSES_REBUILT: usize = 128;
const SAMPLE_SEED: u64 = 0x6c69_6b65_6c79; // "likely"

/// At most this many likely pairs (each costs every free pose a sphere test); a pair joins
/// only if it is in contact in at least `MIN_SHARE` of the sample's colliding poses that no
/// earlier pair covers. (16 and 0.5%: within 2% of the fewest instructions per pose of the
/// settings tried, 4 to 48 pairs and 0.5% to 2%, on every bundled scene.)
const MAX_LIKELY: usize = 16;
const MIN_SHARE: f64 = 0.005;

/// No pair (`Scratch::last_hit` before any hit).
const NO_PAIR: u32 = u32::MAX;

/// Whether some candidate pair of pose `q` (length K) `fails` (a pure function of the placed
/// pose and the pair; its flag, whether the four-pose broad phase's box tests kept the pair,
/// only lets it skip a filter), trying pairs in the fast path's order (module docs) and stopping at the
/// first that fails; `Err` for a pair `fails` cannot decide, met before any that fails.
fn some_pair_fails<F>(model: &RobotModel, q: &[f64], s: &mut Scratch, first: First, mut fails: F) -> std::result::Result<bool, Undecided>
where
    F: FnMut(&mut Scratch, usize, bool) -> std::result::Result<bool, Undecided>,
{
    first_pairs_fail(model, q, s, &mut fails, first).unwrap_or_else(|| near_pair_fails(model, q, s, &mut fails))
}

/// What a pose check tries before its near pairs (module docs, "Order").
///
/// Which pairs are tried first changes only the cost where the narrow phase decides every pair
/// it meets: contact is exact, whatever the order. A pair it cannot decide is met in another
/// order, so a pose with such a pair and another in contact may answer `true` one way and
/// `Undecided` the other (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum First {
    /// The last pair hit, then the model's likely pairs (`likely_pairs`: poses drawn over the
    /// joint space, which collide often; the labelling batches' poses).
    Likely,
    /// The last pair hit alone: the planner's states, mostly free, where the likely pairs cost
    /// each free state its tests and saved nothing measurable (MotionBenchMaker's second plans:
    /// the same instructions either way), and whose first plan on a new scene then never draws
    /// their sample (`likely_pairs`, 1.5 M instructions a MotionBenchMaker scene).
    LastHit,
}

/// `some_pair_fails`' first phase, on the last pair hit and (`First::Likely`) the likely pairs:
/// `Some` when one of them fails (or cannot be decided), `None` when the near pairs must be
/// tried (`near_pair_fails`, on the same placed pose).
fn first_pairs_fail<F>(
    model: &RobotModel,
    q: &[f64],
    s: &mut Scratch,
    fails: &mut F,
    first: First,
) -> Option<std::result::Result<bool, Undecided>>
where
    F: FnMut(&mut Scratch, usize, bool) -> std::result::Result<bool, Undecided>,
{
    let pose = s.pose_stamp();
    let last = (s.last_hit != NO_PAIR).then_some(s.last_hit);
    // (a pair proven clear at this pose's joint value fails no test: `motion::prove_apart`)
    let apart = model.apart();
    let proven = |k: usize| apart.is_some_and(|a| a[k].holds(q));
    let likely: &[u32] = if first == First::Likely { likely_pairs(model) } else { &[] };
    for k in last.into_iter().chain(likely.iter().copied()) {
        let k = k as usize;
        if s.tested[k] == pose {
            continue;
        }
        s.tested[k] = pose;
        if model.broad.may_touch(&s.broad, k) && !proven(k) {
            match fails(s, k, false) {
                Ok(false) => {}
                hit => {
                    if hit.is_ok() {
                        s.last_hit = k as u32;
                    }
                    return Some(hit);
                }
            }
        }
    }
    None
}

/// `some_pair_fails`' second phase: the near pairs the first did not try.
fn near_pair_fails<F>(model: &RobotModel, q: &[f64], s: &mut Scratch, fails: &mut F) -> std::result::Result<bool, Undecided>
where
    F: FnMut(&mut Scratch, usize, bool) -> std::result::Result<bool, Undecided>,
{
    let pose = s.pose_stamp();
    let apart = model.apart();
    let proven = |k: usize| apart.is_some_and(|a| a[k].holds(q));
    let (near, boxed) = s.take_near(model);
    let mut hit = Ok(false);
    for &k in &near {
        if s.tested[k as usize] != pose && !proven(k as usize) {
            hit = fails(s, k as usize, boxed);
            if hit != Ok(false) {
                if hit.is_ok() {
                    s.last_hit = k;
                }
                break;
            }
        }
    }
    s.near = near;
    hit
}

/// `per_pose` on each pose of a `(B, K)` row-major batch, in pose order, in parallel on rayon's
/// current pool, four `Scratch`es per work item (`collide::Scratch4`). `per_pose` runs in two
/// phases (`first_pairs_fail`, then `near_pair_fails` where the first decides nothing), so
/// that the near pairs of four poses are found at once, and only when one of them needs them.
/// Every pose is decided alone, so the result does not depend on the number of threads; the
/// first undecided pose is the error, named.
fn batch<F1, F2>(model: &RobotModel, poses: &[f64], first: F1, second: F2) -> Result<Vec<bool>>
where
    F1: Fn(&[f64], &mut Scratch) -> Option<std::result::Result<bool, Undecided>> + Sync,
    F2: Fn(&[f64], &mut Scratch) -> std::result::Result<bool, Undecided> + Sync,
{
    model.check_poses(poses)?;
    let k = model.njoint();
    likely_pairs(model);
    let chunks: Vec<Result<Vec<bool>>> = crate::threads::map_chunks(
        poses,
        CHUNK * k,
        || Scratch4::new(model),
        |s, (c, chunk)| {
            crate::cancel::check()?;
            let mut out = Vec::with_capacity(chunk.len() / k);
            s.for_each_lazy(
                model,
                chunk,
                false,
                |_, q, s| first(q, s),
                |_, q, s| second(q, s),
                |i, r| {
                    out.push(r.map_err(|e| e.error(model, format!("pose {}", c * CHUNK + i)))?);
                    Ok(())
                },
            )?;
            Ok(out)
        },
    );
    Ok(first_error(chunks)?.concat())
}

/// The first of the row-major `states` (length K each) that collides or that the narrow phase
/// cannot decide, in their order, with its answer (`collides_pose`'s); None when every one is
/// free. Four are placed at a time (`Scratch4`: forward kinematics, spheres and near pairs in
/// lanes), so up to three past the first that collides are placed too. The last pair hit is
/// tried first, then the near pairs (`First::LastHit`): not the likely pairs, which cost each
/// free state their tests (an edge's states after its end state, which the planner checks
/// first, are mostly free; without them, MotionBenchMaker's middle problems take 4 % fewer
/// instructions and its slowest 15 % take 9 % fewer, for the same paths).
///
/// Where the narrow phase decides every pair it meets, the answer is `collides_pose`'s state by
/// state: contact is exact, whichever filter let the pair through. A pair it cannot decide is
/// met by fewer filters in lanes (the four-pose box test keeps pairs the scalar path's sphere
/// against box test rejects) and in another order (each lane's last hit first), so a state the
/// lanes find undecided is checked again, and those after it, one by one on `one` (the scalar
/// path the planner used before): an edge the scalar check finds blocked or free is not turned
/// into an error.
pub(crate) fn first_colliding(
    model: &RobotModel,
    states: &[f64],
    s: &mut Scratch4,
    one: &mut Scratch,
) -> Option<(usize, std::result::Result<bool, Undecided>)> {
    let mut found = None;
    let _ = s.for_each_lazy(
        model,
        states,
        false,
        |_, q, s| first_pairs_fail(model, q, s, &mut in_contact(model), First::LastHit),
        |_, q, s| near_pair_fails(model, q, s, &mut in_contact(model)),
        |i, r| {
            if r == Ok(false) {
                return Ok(());
            }
            found = Some((i, r));
            Err(())
        },
    );
    let k = model.njoint();
    match found {
        Some((at, Err(_))) => states
            .chunks_exact(k)
            .enumerate()
            .skip(at)
            .map(|(i, q)| (i, collides_pose_with(model, q, one, First::LastHit)))
            .find(|(_, r)| *r != Ok(false)),
        found => found,
    }
}

/// Whether pose `q` (length K) collides: `label_pose(..).collides()`, by the fast path; `Err`
/// for a pair the narrow phase cannot decide, met before any pair in contact.
pub fn collides_pose(model: &RobotModel, q: &[f64], s: &mut Scratch) -> std::result::Result<bool, Undecided> {
    collides_pose_with(model, q, s, First::Likely)
}

/// `collides_pose`, trying `first` before the near pairs.
pub(crate) fn collides_pose_with(model: &RobotModel, q: &[f64], s: &mut Scratch, first: First) -> std::result::Result<bool, Undecided> {
    s.place(model, q, false);
    some_pair_fails(model, q, s, first, in_contact(model))
}

/// The pair test of `collides`: in contact (the flag: the pair passed the four-pose box tests,
/// `Scratch::in_contact_after`).
fn in_contact(model: &RobotModel) -> impl FnMut(&mut Scratch, usize, bool) -> std::result::Result<bool, Undecided> + '_ {
    move |s, k, boxed| s.in_contact_after(model, k, boxed)
}

/// The pair test of `certified`: not clear at `clearance`.
fn not_clear(model: &RobotModel, clearance: f64) -> impl FnMut(&mut Scratch, usize, bool) -> std::result::Result<bool, Undecided> + '_ {
    move |s, k, _| s.clear_of(model, k, clearance).map(|clear| !clear)
}

/// Whether each pose of a `(B, K)` row-major batch collides, in pose order, in parallel on
/// rayon's current pool. Every pose is decided alone, so the result does not depend on the
/// number of threads.
pub fn collides_batch(model: &RobotModel, poses: &[f64]) -> Result<Vec<bool>> {
    batch(
        model,
        poses,
        |q, s| first_pairs_fail(model, q, s, &mut in_contact(model), First::Likely),
        |q, s| near_pair_fails(model, q, s, &mut in_contact(model)),
    )
}

/// Whether pose `q` (length K) is certified free: no candidate pair in contact and every
/// candidate pair more than `clearance` (in (0, `MAX_CLEARANCE`]) metres apart, i.e.
/// `!collides && min_distance > clearance` of `label_pose` with distances, decided pair by pair
/// (`Scratch::clear_of`) and stopping at the first pair that is not clear, in `collides_pose`'s
/// order. A pair the broad phase drops is more than `MAX_CLEARANCE` beyond its margin
/// (`model/broad.rs`), so clear. `Err` for a pair the narrow phase cannot decide, met before any pair
/// that is not clear.
pub fn certified_pose(model: &RobotModel, q: &[f64], clearance: f64, s: &mut Scratch) -> std::result::Result<bool, Undecided> {
    certified_pose_with(model, q, clearance, s, First::Likely)
}

/// `certified_pose`, trying `first` before the near pairs.
pub(crate) fn certified_pose_with(
    model: &RobotModel,
    q: &[f64],
    clearance: f64,
    s: &mut Scratch,
    first: First,
) -> std::result::Result<bool, Undecided> {
    s.place(model, q, false);
    some_pair_fails(model, q, s, first, not_clear(model, clearance)).map(|fails| !fails)
}

/// Whether each pose of a `(B, K)` row-major batch is certified free at `clearance` metres
/// (`certified_pose`), in pose order, in parallel on rayon's current pool; independent of the
/// number of threads.
/// A pose the robot cannot take (outside a limit, off a coupling: `RobotModel::feasible`) is
/// never certified.
pub fn certified_batch(model: &RobotModel, poses: &[f64], clearance: f64) -> Result<Vec<bool>> {
    check_clearance(clearance)?;
    // (in `batch`'s terms: a pose "fails" when it is not certified)
    let fails = batch(
        model,
        poses,
        |q, s| {
            if model.feasible(q) {
                first_pairs_fail(model, q, s, &mut not_clear(model, clearance), First::Likely)
            } else {
                Some(Ok(true))
            }
        },
        |q, s| near_pair_fails(model, q, s, &mut not_clear(model, clearance)),
    )?;
    Ok(fails.into_iter().map(|fails| !fails).collect())
}

/// The model's likely pairs, computed on first use (on the calling thread, without rayon:
/// a worker that waits here can never be asked to run this initialisation itself).
pub fn likely_pairs(model: &RobotModel) -> &[u32] {
    &model.likely.get_or_init(|| greedy_cover(model)).order
}

/// A greedy cover of the colliding poses of a seeded uniform sample: repeatedly the pair in
/// contact in the most colliding poses that no earlier pair covers (ties: the lower index).
/// Empty when the model has no sampling ranges (an unlimited slide joint). A sample pose the
/// narrow phase cannot decide is left out: the cover only orders pairs, it labels nothing (the
/// caller's own call on such a pose fails).
///
/// A model rebuilt from one that had drawn its sample (a scene update) takes over the contacts
/// of the pairs both share (`model::InheritedLikely`) and tests only its other pairs in each
/// pose: the world's new obstacles against the robot, where labelling every pair of 128 Panda
/// poses took 1.3 ms of a MotionBenchMaker problem's first plan. Whether a pair is in contact
/// in a pose is a function of the pair and the pose alone, whatever else is tested
/// (`collide::Scratch::in_contact`), so the contacts, and the cover, are those of labelling
/// the sample with `label_pose` (tested).
fn greedy_cover(model: &RobotModel) -> Likely {
    let Ok(ranges) = model.sampling_ranges() else {
        return Likely::default();
    };
    let k = ranges.len();
    if k == 0 || model.pairs.is_empty() {
        return Likely::default();
    }
    let n = if model.inherited.is_some() { SAMPLE_POSES_REBUILT } else { SAMPLE_POSES };
    let taken = model.inherited.as_ref().and_then(|i| i.likely.as_ref()).filter(|l| l.n >= n);
    sample_cover(model, &ranges, n, taken)
}

/// `greedy_cover` over the first `n` poses of the seeded sample, taking over `taken`'s contacts.
fn sample_cover(model: &RobotModel, ranges: &[[f64; 2]], n: usize, taken: Option<&InheritedLikely>) -> Likely {
    let k = ranges.len();
    let npairs = model.pairs.len();
    // (pose by pose from each block's stream: the first `n` poses of any larger sample)
    let mut poses = vec![0.0; n * k];
    for (c, block) in poses.chunks_mut(BLOCK * k).enumerate() {
        fill_block(ranges, SAMPLE_SEED, c, block);
    }
    let mut scratch = Scratch::new(model);
    let opts = LabelOptions { pairs: true, distance: false };
    let mut contacts: Vec<Vec<u32>> = vec![Vec::new(); npairs];
    let mut undecided: Vec<(u32, u32)> = Vec::new();
    // (a sample pose labelled whole: every pair's contacts, or the pair it stopped at)
    let label = |i: usize, q: &[f64], s: &mut Scratch, contacts: &mut Vec<Vec<u32>>, undecided: &mut Vec<(u32, u32)>| {
        let mut hits = Vec::new();
        match label_pose(model, q, s, opts, &mut hits) {
            Ok(_) => hits.iter().for_each(|&p| contacts[p as usize].push(i as u32)),
            Err(u) => undecided.push((i as u32, u.pair)),
        }
    };
    match taken {
        None => {
            for (i, q) in poses.chunks_exact(k).enumerate() {
                label(i, q, &mut scratch, &mut contacts, &mut undecided);
            }
        }
        Some(old) => {
            let kept = |i: &u32| (*i as usize) < n;
            let mut fresh = vec![false; npairs];
            for (p, c) in old.contacts.iter().enumerate() {
                match c {
                    Some(c) => contacts[p] = c.iter().copied().filter(kept).collect(),
                    None => fresh[p] = true,
                }
            }
            // Old undecided poses: undecided here too when the pair is shared, else labelled whole.
            let mut whole = vec![false; n];
            for &(i, p) in old.undecided.iter().filter(|(i, _)| kept(i)) {
                match p {
                    Some(p) => undecided.push((i, p)),
                    None => whole[i as usize] = true,
                }
            }
            let apart = model.apart();
            for (i, q) in poses.chunks_exact(k).enumerate() {
                if whole[i] {
                    label(i, q, &mut scratch, &mut contacts, &mut undecided);
                    continue;
                }
                scratch.place(model, q, false);
                let (near, boxed) = scratch.take_near(model);
                for &p in near.iter().filter(|&&p| fresh[p as usize]) {
                    let p = p as usize;
                    if apart.is_some_and(|a| a[p].holds(q)) {
                        continue;
                    }
                    match scratch.in_contact_after(model, p, boxed) {
                        Ok(true) => contacts[p].push(i as u32),
                        Ok(false) => {}
                        Err(u) => {
                            undecided.push((i as u32, u.pair));
                            break;
                        }
                    }
                }
                scratch.near = near;
            }
        }
    }
    undecided.sort_unstable();
    undecided.dedup_by_key(|u| u.0);
    let mut left_out = vec![false; n];
    for &(i, _) in &undecided {
        left_out[i as usize] = true;
    }
    // Per pair, the colliding sample poses it is in contact in (the poses labelled).
    let poses_of: Vec<Vec<u32>> = contacts.iter().map(|c| c.iter().copied().filter(|&i| !left_out[i as usize]).collect()).collect();
    let mut colliding = vec![false; n];
    for &i in poses_of.iter().flatten() {
        colliding[i as usize] = true;
    }
    let colliding = colliding.iter().filter(|&&c| c).count();
    let min_gain = ((colliding as f64 * MIN_SHARE).ceil() as usize).max(1);
    let mut covered = vec![false; n];
    let mut order = Vec::new();
    while order.len() < MAX_LIKELY {
        let gain = |p: &[u32]| p.iter().filter(|&&i| !covered[i as usize]).count();
        let Some((best, n)) = poses_of.iter().enumerate().map(|(p, of)| (p, gain(of))).rev().max_by_key(|&(_, n)| n) else {
            break;
        };
        if n < min_gain {
            break;
        }
        for &i in &poses_of[best] {
            covered[i as usize] = true;
        }
        order.push(best as u32);
    }
    Likely { order, n, contacts: poses_of, undecided }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::collide::label_batch;
    use crate::joints::sample::sample_uniform;
    use crate::model::desc::ModelDesc;

    /// A scene's model and its world geoms edited (one removed, one moved), rebuilt from it.
    fn edited(scene: &str) -> (RobotModel, RobotModel, ModelDesc) {
        let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
        let desc: ModelDesc = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let model = RobotModel::new(desc.clone()).unwrap();
        let world: Vec<usize> = (0..desc.geom_body.len()).filter(|&g| desc.geom_body[g] == 0).collect();
        let mut edited = desc.clone();
        edited.geom_pos[world[1]][0] += 0.05;
        let g = world[0];
        edited.geom_id.remove(g);
        edited.geom_type.remove(g);
        edited.geom_body.remove(g);
        edited.geom_pos.remove(g);
        edited.geom_quat.remove(g);
        edited.geom_size.remove(g);
        edited.geom_contype.remove(g);
        edited.geom_conaffinity.remove(g);
        edited.geom_margin.remove(g);
        edited.geom_mesh.remove(g);
        likely_pairs(&model);
        let rebuilt = model.rebuilt(&desc, edited.clone()).unwrap();
        (model, rebuilt, edited)
    }

    /// A robot without a sampling box (an unlimited slide) draws no sample: a model rebuilt from
    /// it takes none over, and draws none either.
    #[test]
    fn a_robot_without_a_sample_is_rebuilt() {
        let mut desc = crate::planning::motion::tests::arm_desc();
        desc.jnt_limited[2] = false;
        let model = RobotModel::new(desc.clone()).unwrap();
        crate::planning::motion::prove_apart(&model);
        assert!(likely_pairs(&model).is_empty());
        let rebuilt = model.rebuilt(&desc, desc.clone()).unwrap();
        assert!(rebuilt.inherited.as_ref().is_some_and(|i| i.likely.is_none()));
        assert!(likely_pairs(&rebuilt).is_empty());
    }

    /// A model rebuilt after an edit of its world takes over the sample contacts of the pairs it
    /// shares and tests only the others, and its cover, contacts and left-out poses are those
    /// of labelling the whole sample itself, pair for pair; so are a model rebuilt from that one.
    #[test]
    fn rebuilt_models_take_over_the_sample_and_cover_as_if_labelling_it() {
        for scene in ["panda_blocks", "ur5e_wall_box", "vx300s_clutter"] {
            let (_, rebuilt, edited) = edited(scene);
            let taken = rebuilt.inherited.as_ref().unwrap().likely.as_ref().unwrap();
            let n_taken = taken.contacts.iter().filter(|c| c.is_some()).count();
            assert!(n_taken > 0 && n_taken < taken.contacts.len(), "{scene}: {n_taken} of {}", taken.contacts.len());
            let ranges = rebuilt.sampling_ranges().unwrap();
            likely_pairs(&rebuilt);
            let again = rebuilt.rebuilt(&edited, edited.clone()).unwrap();
            likely_pairs(&again);
            for m in [&rebuilt, &again] {
                let got = m.likely.get().unwrap();
                let whole = sample_cover(m, &ranges, SAMPLE_POSES_REBUILT, None);
                assert_eq!(got.n, SAMPLE_POSES_REBUILT);
                assert_eq!(got.order, whole.order, "{scene}");
                assert!(!got.order.is_empty() && got.contacts.iter().any(|c| !c.is_empty()), "{scene}");
                let sorted = |c: &Vec<Vec<u32>>| {
                    c.iter()
                        .map(|c| {
                            let mut c = c.clone();
                            c.sort_unstable();
                            c
                        })
                        .collect::<Vec<_>>()
                };
                assert_eq!(sorted(&got.contacts), sorted(&whole.contacts), "{scene}");
                let poses = |u: &Vec<(u32, u32)>| u.iter().map(|x| x.0).collect::<Vec<_>>();
                assert_eq!(poses(&got.undecided), poses(&whole.undecided), "{scene}");
            }
        }
    }

    /// `first_colliding` finds the state `collides_pose` finds scanning in order, on runs of
    /// every length from 0 to 13 (whole quads and remainders), with the colliding state
    /// anywhere in a quad, and one scratch reused across runs.
    #[test]
    fn first_colliding_is_the_first_collides_pose_finds() {
        let mut hits = [0usize; 4];
        for scene in ["panda_blocks", "shadow_hand", "vx300s_clutter"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
            let k = model.njoint();
            let poses = sample_uniform(&model.sampling_ranges().unwrap(), 600, 7).unwrap();
            let (mut s, mut s4) = (Scratch::new(&model), Scratch4::new(&model));
            let mut start = 0;
            for len in (0..=13).cycle().take(90) {
                let run = &poses[start * k..(start + len) * k];
                start += len;
                let scan =
                    run.chunks_exact(k).enumerate().map(|(i, q)| (i, collides_pose(&model, q, &mut s))).find(|(_, r)| *r != Ok(false));
                let got = first_colliding(&model, run, &mut s4, &mut Scratch::new(&model));
                assert_eq!(got, scan, "{scene}: run of {len}");
                if let Some((i, _)) = got {
                    hits[i % 4] += 1;
                }
            }
        }
        assert!(hits.iter().all(|&h| h > 0), "first hits at each lane {hits:?}");
    }

    #[test]
    fn fast_path_agrees_with_the_labels_on_any_thread_count() {
        let mut desc = ModelDesc::example_pendulum();
        desc.body_pos[1][2] = 0.45; // the bob reaches 0.05 below the floor when hanging
        let model = RobotModel::new(desc).unwrap();
        let poses = sample_uniform(&model.sampling_ranges().unwrap(), 5000, 2).unwrap();
        let labels = label_batch(&model, &poses, LabelOptions::default()).unwrap();
        let want: Vec<bool> = labels.labels.iter().map(|l| l.collides()).collect();
        assert!(want.iter().any(|&c| c) && want.iter().any(|&c| !c));
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            assert_eq!(pool.install(|| collides_batch(&model, &poses).unwrap()), want);
        }
        assert_eq!(likely_pairs(&model), &[0]);
    }

    /// Certification agrees with the labels' "not colliding and min_distance > clearance" on a
    /// pendulum whose bob passes 0.05 m below the floor, at poses spread over the circle and
    /// packed around the two poses where the bob just touches it (distances from -2e-6 to 2e-6
    /// m, so several fall within the clearance), for clearances 1e-9, 1e-7 and 1e-6, and with
    /// no margin, a positive one, and a negative one (regression: the broad phase used to drop
    /// a pair with a negative margin that was within the clearance, which the labels measure).
    #[test]
    fn certification_agrees_with_the_labelled_distances() {
        for margins in [[0.0, 0.0], [0.01, 0.005], [-0.01, 0.0]] {
            let mut desc = ModelDesc::example_pendulum();
            desc.body_pos[1][2] = 0.45;
            desc.geom_margin = margins.to_vec();
            let model = RobotModel::new(desc).unwrap();
            let mut poses = sample_uniform(&model.sampling_ranges().unwrap(), 4000, 3).unwrap();
            let opts = LabelOptions { pairs: false, distance: true };
            let labels = label_batch(&model, &poses, opts).unwrap();
            let dist = |q: f64| label_batch(&model, &[q], opts).unwrap().labels[0].min_distance;
            // the touching angles: bisect each sign change of the distance along the sample,
            // then pack poses around each
            let touch: Vec<f64> = {
                let mut by_angle: Vec<(f64, f64)> = poses.iter().zip(&labels.labels).map(|(&q, l)| (q, l.min_distance)).collect();
                by_angle.sort_by(|a, b| a.0.total_cmp(&b.0));
                let brackets: Vec<(f64, f64)> =
                    by_angle.windows(2).filter(|w| (w[0].1 > 0.0) != (w[1].1 > 0.0)).map(|w| (w[0].0, w[1].0)).collect();
                brackets
                    .into_iter()
                    .map(|(mut lo, mut hi)| {
                        let free_lo = dist(lo) > 0.0;
                        for _ in 0..60 {
                            let mid = 0.5 * (lo + hi);
                            if (dist(mid) > 0.0) == free_lo {
                                lo = mid
                            } else {
                                hi = mid
                            }
                        }
                        lo
                    })
                    .collect()
            };
            assert!(!touch.is_empty());
            for &t in &touch {
                poses.extend((-200..=200).map(|i| t + i as f64 * 1e-8));
            }
            let labels = label_batch(&model, &poses, opts).unwrap();
            for clearance in [1e-9, 1e-7, 1e-6] {
                let want: Vec<bool> = labels.labels.iter().map(|l| !l.collides() && l.min_distance > clearance).collect();
                let near = labels.labels.iter().filter(|l| l.min_distance.abs() <= 2e-6).count();
                assert!(near >= 4, "{near} poses within 2e-6 m of contact");
                for threads in [1, 2] {
                    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                    let got = pool.install(|| certified_batch(&model, &poses, clearance).unwrap());
                    assert_eq!(got, want, "margins {margins:?}, clearance {clearance}");
                }
            }
            assert!(certified_batch(&model, &poses, 1e-5).is_err());
            assert!(certified_batch(&model, &poses, 0.0).is_err());
            assert!(certified_batch(&model, &poses, f64::NAN).is_err());
        }
    }

    #[test]
    fn bad_poses_are_errors_not_panics() {
        let model = RobotModel::new(ModelDesc::example_pendulum()).unwrap();
        assert!(collides_batch(&model, &[]).is_err());
        assert!(collides_batch(&model, &[f64::INFINITY]).is_err());
    }

    /// The planner's pose checks without the likely pairs (`First::LastHit`) answer as the
    /// labeller does, pose by pose, in contact and certified free (1 µm), from one scratch carried
    /// through the poses (so the last hit is often a pair the next pose does not touch), and
    /// never draw the likely pairs' sample.
    #[test]
    fn pose_checks_from_the_last_hit_answer_as_the_labeller() {
        for scene in ["panda_blocks", "ur5e_wall_box", "shadow_hand", "vx300s_clutter"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let desc: ModelDesc = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            let model = RobotModel::new(desc).unwrap();
            let k = model.njoint();
            let poses = sample_uniform(&model.sampling_ranges().unwrap(), 1500, 7).unwrap();
            let labels = label_batch(&model, &poses, LabelOptions { pairs: false, distance: true }).unwrap().labels;
            let mut s = Scratch::new(&model);
            let (mut hits, mut clear) = (0, 0);
            for (i, (q, l)) in poses.chunks_exact(k).zip(&labels).enumerate() {
                let c = collides_pose_with(&model, q, &mut s, First::LastHit).unwrap();
                assert_eq!(c, l.collides(), "{scene} pose {i}");
                let certified = certified_pose_with(&model, q, 1e-6, &mut s, First::LastHit).unwrap();
                assert_eq!(certified, !l.collides() && l.min_distance > 1e-6, "{scene} pose {i}");
                hits += c as usize;
                clear += certified as usize;
            }
            assert!(hits > 100 && clear > 100, "{scene}: {hits} in contact, {clear} certified");
            assert!(model.likely.get().is_none(), "{scene}: the likely pairs were drawn");
        }
    }
}
