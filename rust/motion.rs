//! Straight motions in joint space, certified continuously: conservative advancement.
//!
//! A motion is `q(t) = a + t·Δ`, `t ∈ [0, 1]`, with `Δ` the short arc on continuous hinges (the
//! SO(2) interpolation `interpolate.rs` replays, states wrapped by `angles::wrap`). It is
//! *certified* when every candidate pair keeps a signed distance above `need = max(margin,
//! clearance)` at **every** `t`, not only at samples. The proof, pair by pair:
//!
//! 1. **How fast a pair can close** ([`Levers`]). Let `c` be the deepest common ancestor body
//!    of the pair's two bodies. The pair's distance depends only on the joints strictly below
//!    `c` (those at or above move both geoms rigidly together). A point `x` of a geom moves, in
//!    `c`'s frame, at `|ẋ| ≤ Σ_j |q̇_j|·R_j`: for a hinge, `|ω_j × (x − p_j)| ≤ |x − p_j| ≤ R_j`
//!    with `R_j` an upper bound on the distance from the joint's anchor `p_j` to any point of the
//!    geom in every configuration (from the chain's fixed offsets, `joint_reach`); for a slide,
//!    `R_j = 1`. Along the motion `|q̇_j| = |Δ_j|`, so the pair's distance changes at most at rate
//!    `M = Σ_j (R_j(g₁) + R_j(g₂))·|Δ_j|` per unit of `t` (distance between two sets is
//!    1-Lipschitz in the motion of each).
//! 2. **What a state proves.** If the pair's distance at `t₀` is `d > need`, it stays above
//!    `need` for `|t − t₀| < (d − need)/M`, the state's *radius* for the pair.
//! 3. **What an interval proves.** `[t₀, t₁]` is proven for the pair when `r(t₀) + r(t₁) ≥ t₁ −
//!    t₀`. Intervals that are not are halved at their midpoint, which is placed and measured for
//!    the pairs still open there only, level by level (so a collision anywhere on the motion is
//!    met early, as by the sampled check's coarse-to-fine order).
//!
//! Distances are lower bounds: first the pair's bounding spheres (`broad.rs`), enough wherever
//! the pair is far; else the exact distance (`collide::Scratch::pair_distance`: the support point
//! for a plane, parry's GJK for two convex shapes, accurate to ~1e-14 relative), reduced by
//! [`DISTANCE_SLACK`] for rounding. A state with some pair not above `need` ends the motion:
//! [`Motion::Blocked`]. The halving stops when an open interval moves no joint more than
//! [`MIN_STEP`]: a motion that grazes a pair within ~`M·MIN_STEP` of `need` may be
//! [`Motion::Unproven`] though free; nothing unproven is ever called free.

use crate::angles::wrap;
use crate::broad::MAX_CLEARANCE;
use crate::collide::{first_error, Scratch, Undecided};
use crate::error::{Error, Result};
use crate::model::RobotModel;

/// Radians / metres: the smallest joint move of an interval the certificate halves further.
pub const MIN_STEP: f64 = 1e-7;
/// Most states one motion may place before it is called unproven.
pub const MAX_STATES: usize = 1 << 16;
/// Relative and absolute (metres) rounding slack taken off every measured distance.
const DISTANCE_SLACK: f64 = 1e-9;

/// The verdict on one motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    /// Every pair stays above its `need` at every state of the motion.
    Certified,
    /// The placed state at `t` has a pair at or below its `need`: in contact, or closer than
    /// the clearance.
    Blocked(f64),
    /// Neither proven nor refuted within [`MIN_STEP`] / [`MAX_STATES`].
    Unproven,
}

/// The joint space: bounds per joint and which joints wrap (continuous hinges).
#[derive(Clone, Debug)]
pub(crate) struct Space {
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
    pub wraps: Vec<bool>,
}

impl Space {
    /// The model's sampling ranges (`RobotModel::sampling_ranges`) and continuous hinges.
    pub fn of(model: &RobotModel) -> Result<Space> {
        let ranges = model.sampling_ranges()?;
        Ok(Space { lo: ranges.iter().map(|r| r[0]).collect(), hi: ranges.iter().map(|r| r[1]).collect(), wraps: model.continuous() })
    }

    /// `b − a`, the short arc on wrapping joints.
    pub fn delta(&self, a: &[f64], b: &[f64], out: &mut [f64]) {
        for k in 0..a.len() {
            let d = b[k] - a[k];
            out[k] = if self.wraps[k] { wrap(d) } else { d };
        }
    }

    pub fn distance(&self, a: &[f64], b: &[f64]) -> f64 {
        let mut s = 0.0;
        for k in 0..a.len() {
            let d = b[k] - a[k];
            let d = if self.wraps[k] { wrap(d) } else { d };
            s += d * d;
        }
        s.sqrt()
    }

    /// `a + t·Δ` into `out`, wrapping joints mapped back into [-π, π).
    pub fn along(&self, a: &[f64], d: &[f64], t: f64, out: &mut [f64]) {
        for k in 0..a.len() {
            let v = a[k] + t * d[k];
            out[k] = if self.wraps[k] { wrap(v) } else { v.clamp(self.lo[k], self.hi[k]) };
        }
    }
}

/// Per candidate pair and joint: how fast (metres per radian, or per metre of a slide) the pair's
/// distance can change when that joint alone moves (module docs, step 1); 0 for joints at or
/// above the pair's common ancestor. Computed once per model (`RobotModel::lever_rows`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Levers<'m> {
    k: usize,
    /// Pair-major `(npairs, K)`.
    rows: &'m [f64],
}

impl<'m> Levers<'m> {
    pub(crate) fn of(model: &'m RobotModel) -> Levers<'m> {
        Levers { k: model.njoint(), rows: model.lever_rows.get_or_init(|| lever_rows(model)) }
    }

    /// The pair's rate `M` (metres per unit of `t`) for joint moves `|Δ|`; an infinite lever
    /// counts only for a joint that moves.
    #[inline]
    fn rate(&self, pair: usize, abs_delta: &[f64]) -> f64 {
        let row = &self.rows[pair * self.k..(pair + 1) * self.k];
        row.iter().zip(abs_delta).filter(|(_, &d)| d != 0.0).map(|(r, d)| r * d).sum()
    }
}

/// The `(npairs, K)` lever table of `Levers`.
fn lever_rows(model: &RobotModel) -> Vec<f64> {
    {
        let k = model.njoint();
        let mut rows = vec![0.0; model.pairs.len() * k];
        let ancestors = |mut b: usize| {
            let mut out = vec![b];
            while b != 0 {
                b = model.body_parent[b];
                out.push(b);
            }
            out
        };
        for (p, pair) in model.pairs.iter().enumerate() {
            let (b1, b2) = (model.geoms[pair.g1].body, model.geoms[pair.g2].body);
            let (up1, up2) = (ancestors(b1), ancestors(b2));
            let common = *up1.iter().find(|b| up2.contains(b)).expect("the world is a common ancestor");
            for (g, up) in [(pair.g1, &up1), (pair.g2, &up2)] {
                for &b in up.iter().take_while(|&&b| b != common) {
                    let (j0, j1) = model.body_joints[b];
                    for j in j0..j1 {
                        rows[p * k + j] += joint_reach(model, j, g, up);
                    }
                }
            }
        }
        rows
    }
}

/// The largest displacement a slide joint can take from `qpos0` within its limits (infinite
/// for an unlimited slide).
fn slide_reach(model: &RobotModel, j: usize) -> f64 {
    if model.limited[j] {
        let [lo, hi] = model.limits[j];
        let q0 = model.joints[j].qpos0;
        (lo - q0).abs().max((hi - q0).abs())
    } else {
        f64::INFINITY
    }
}

/// Joint `j`'s lever on geom `g` (a geom below it; `up` is `g`'s body and its ancestors, from
/// `g`'s body up to the world): 1 for a slide; for a hinge, an upper bound on the distance from
/// its anchor to any point of the geom in any configuration.
///
/// The walk keeps a point `π` fixed in the current frame and a bound `cost ≥ |p_j − π|` (world):
/// each later hinge (anchor `α`, fixed while it turns) adds `|π − α|` and moves `π` to `α`; each
/// later slide adds its largest displacement; a body's fixed offset maps `π` into the child's
/// coordinates exactly. At the geom: `|π − centre| + radius`, its bounding sphere.
fn joint_reach(model: &RobotModel, j: usize, g: usize, up: &[usize]) -> f64 {
    let jnt = &model.joints[j];
    if !jnt.hinge {
        return 1.0;
    }
    let mut pi = jnt.anchor;
    let mut cost = 0.0;
    let later = |b: usize, from: usize, pi: &mut nalgebra::Vector3<f64>, cost: &mut f64| {
        for i in from..model.body_joints[b].1 {
            let ji = &model.joints[i];
            if ji.hinge {
                *cost += (*pi - ji.anchor).norm();
                *pi = ji.anchor;
            } else {
                *cost += slide_reach(model, i);
            }
        }
    };
    later(jnt.body, j + 1, &mut pi, &mut cost);
    // Bodies from the joint's body down to the geom's: `up` reversed, after the joint's body.
    let at = up.iter().position(|&b| b == jnt.body).expect("the joint is above the geom");
    for &b in up[..at].iter().rev() {
        pi = model.body_local[b].inverse_transform_point(&pi.into()).coords;
        later(b, model.body_joints[b].0, &mut pi, &mut cost);
    }
    let geom = &model.geoms[g];
    let centre = (geom.local * nalgebra::Point3::from(geom.shape.obb_center)).coords;
    // (1e-9 relative: rounding of the offsets, far below any distance's own slack)
    (cost + (pi - centre).norm() + geom.shape.radius) * (1.0 + 1e-9)
}

/// One open pair on an interval: its rate and its radii at the two ends.
#[derive(Clone, Copy, Debug)]
struct Open {
    pair: u32,
    rate: f64,
    r0: f64,
    r1: f64,
}

/// Per-thread buffers of the certificate.
pub struct MotionScratch {
    pub(crate) scratch: Scratch,
    abs_delta: Vec<f64>,
    rates: Vec<f64>,
    q: Vec<f64>,
    radius1: Vec<f64>,
    open: Vec<Open>,
    next: Vec<Open>,
    mid: Vec<(Open, f64)>,
    /// States placed by the last call.
    pub states: usize,
    /// Diagnostics: pair measurements, and those that needed more than the spheres (all calls).
    pub measured: usize,
    pub exact: usize,
}

impl MotionScratch {
    pub fn new(model: &RobotModel) -> Self {
        MotionScratch {
            scratch: Scratch::new(model),
            abs_delta: vec![0.0; model.njoint()],
            rates: vec![0.0; model.pairs.len()],
            q: vec![0.0; model.njoint()],
            radius1: vec![0.0; model.pairs.len()],
            open: Vec::new(),
            next: Vec::new(),
            mid: Vec::new(),
            states: 0,
            measured: 0,
            exact: 0,
        }
    }
}

/// Why a measured pair ends the motion.
enum Stop {
    Blocked,
    Undecided(Undecided),
}

pub static DBG: [std::sync::atomic::AtomicUsize; 3] = [std::sync::atomic::AtomicUsize::new(0), std::sync::atomic::AtomicUsize::new(0), std::sync::atomic::AtomicUsize::new(0)];
/// The radius (in `t`) of pair `k`, rate `rate`, in the placed state, for an interval end
/// whose neighbours need `cover_min` and `cover_max` (in `t`) of it: the bounding spheres'
/// radius when it gives `cover_max`, or when a closer measurement could not plausibly give even
/// `cover_min` (then the caller halves the interval, cheaper than measuring); else the
/// separation-axis or GJK bound (`Scratch::pair_lower_bound`). `Err(Blocked)` when the pair is
/// not shown above its need. (Which bound is taken is a matter of cost only: each is a lower
/// bound.)
#[inline]
fn radius(model: &RobotModel, s: &mut Scratch, k: usize, rate: f64, need: f64, cover_min: f64, cover_max: f64) -> std::result::Result<f64, Stop> {
    DBG[0].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let (gap, reach) = model.broad.sphere_gap(&s.broad, k, &model.geoms);
    let gap = gap - need;
    let per = |slack: f64| if rate > 0.0 { slack / rate } else { f64::INFINITY };
    if gap > 0.0 && (gap >= cover_max.max(0.0) * rate || gap + reach < cover_min * rate) {
        return Ok(per(gap));
    }
    let want = need + cover_max.max(0.0) * rate;
    DBG[1].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let d = s.pair_lower_bound(model, k, want * (1.0 + DISTANCE_SLACK) + DISTANCE_SLACK).map_err(Stop::Undecided)?;
    let slack = d - DISTANCE_SLACK * (1.0 + d.abs()) - need;
    if slack <= 0.0 {
        return Err(Stop::Blocked);
    }
    Ok(per(slack.max(gap)))
}

/// Whether the motion `a → a + Δ` is certified (module docs) with every pair above
/// `max(margin, clearance)` metres; `Err` for a pair the narrow phase cannot measure.
/// `space` wraps and clamps the states as the planner's do.
pub(crate) fn certify_motion(
    model: &RobotModel,
    levers: Levers,
    space: &Space,
    a: &[f64],
    delta: &[f64],
    clearance: f64,
    ms: &mut MotionScratch,
) -> std::result::Result<Motion, Undecided> {
    let k = a.len();
    ms.states = 0;
    DBG[2].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut span = 0.0f64;
    for (ad, d) in ms.abs_delta.iter_mut().zip(delta) {
        *ad = d.abs();
        span = span.max(*ad);
    }
    let npairs = model.pairs.len();
    for p in 0..npairs {
        ms.rates[p] = levers.rate(p, &ms.abs_delta);
    }
    let need = |p: usize| model.pairs[p].margin.max(clearance);
    let stop = |e: Stop, t: f64| match e {
        Stop::Blocked => Ok(Motion::Blocked(t)),
        Stop::Undecided(u) => Err(u),
    };
    // The end first (a planner's new state often collides), by spheres wherever they are
    // apart; then the start, exact where the spheres do not close the motion; then the end
    // again, exact, for the pairs still open that it measured by spheres only.
    let mut q = std::mem::take(&mut ms.q);
    q.resize(k, 0.0);
    space.along(a, delta, 1.0, &mut q);
    ms.scratch.place(model, &q, false);
    ms.states += 1;
    for p in 0..npairs {
        match radius(model, &mut ms.scratch, p, ms.rates[p], need(p), 0.0, 0.0) {
            Ok(r) => ms.radius1[p] = r,
            Err(e) => {
                ms.q = q;
                return stop(e, 1.0);
            }
        }
    }
    space.along(a, delta, 0.0, &mut q);
    ms.scratch.place(model, &q, false);
    ms.states += 1;
    ms.open.clear();
    ms.next.clear();
    for p in 0..npairs {
        let r1 = ms.radius1[p];
        if r1 >= 1.0 {
            continue;
        }
        match radius(model, &mut ms.scratch, p, ms.rates[p], need(p), 1.0 - r1, 1.0 - r1) {
            Ok(r0) if r0 + r1 >= 1.0 => {}
            Ok(r0) => ms.next.push(Open { pair: p as u32, rate: ms.rates[p], r0, r1 }),
            Err(e) => {
                ms.q = q;
                return stop(e, 0.0);
            }
        }
    }
    if !ms.next.is_empty() {
        space.along(a, delta, 1.0, &mut q);
        ms.scratch.place(model, &q, false);
        ms.states += 1;
        for o in &ms.next {
            let p = o.pair as usize;
            match radius(model, &mut ms.scratch, p, o.rate, need(p), 1.0 - o.r0, 1.0 - o.r0) {
                Ok(r1) if o.r0 + r1 >= 1.0 => {}
                Ok(r1) => ms.open.push(Open { r1: r1.max(o.r1), ..*o }),
                Err(e) => {
                    ms.q = q;
                    return stop(e, 1.0);
                }
            }
        }
    }
    // Breadth first: intervals of one level, each with its open pairs (contiguous in `open`).
    let mut level: Vec<(f64, usize, usize)> = if ms.open.is_empty() { Vec::new() } else { vec![(0.0, 0, ms.open.len())] };
    let mut width = 1.0f64;
    let mut verdict = Ok(Motion::Certified);
    'levels: while !level.is_empty() {
        if width * span < MIN_STEP {
            verdict = Ok(Motion::Unproven);
            break;
        }
        let half = width * 0.5;
        ms.next.clear();
        let mut next_level = Vec::with_capacity(level.len() * 2);
        for &(t0, start, end) in &level {
            if ms.states >= MAX_STATES {
                verdict = Ok(Motion::Unproven);
                break 'levels;
            }
            let tm = t0 + half;
            space.along(a, delta, tm, &mut q);
            ms.scratch.place(model, &q, false);
            ms.states += 1;
            ms.mid.clear();
            for o in &ms.open[start..end] {
                let p = o.pair as usize;
                // What the midpoint must give to close one half, and both.
                let (c0, c1) = (half - o.r0, half - o.r1);
                match radius(model, &mut ms.scratch, p, o.rate, need(p), c0.min(c1), c0.max(c1)) {
                    Ok(rm) => ms.mid.push((*o, rm)),
                    Err(e) => {
                        verdict = stop(e, tm);
                        break 'levels;
                    }
                }
            }
            let s = ms.next.len();
            ms.next.extend(ms.mid.iter().filter(|(o, rm)| o.r0 + rm < half).map(|&(o, rm)| Open { r1: rm, ..o }));
            if ms.next.len() > s {
                next_level.push((t0, s, ms.next.len()));
            }
            let s = ms.next.len();
            ms.next.extend(ms.mid.iter().filter(|(o, rm)| rm + o.r1 < half).map(|&(o, rm)| Open { r0: rm, ..o }));
            if ms.next.len() > s {
                next_level.push((tm, s, ms.next.len()));
            }
        }
        std::mem::swap(&mut ms.open, &mut ms.next);
        level = next_level;
        width = half;
    }
    ms.q = q;
    verdict
}

/// Motions per parallel work item (fixed, so the split never depends on the thread count).
const CHUNK: usize = 16;

/// The verdict on each motion `starts[i] → goals[i]` (`(B, K)` row-major each; continuous
/// hinges along the short arc, other joints straight and unclamped) with every pair above
/// `max(margin, clearance)` metres, `clearance` in `(0, MAX_CLEARANCE]`, and the states each
/// placed; in motion order, in parallel on rayon's current pool. Every motion is decided
/// alone, so the result does not depend on the number of threads.
pub fn certify_motions(model: &RobotModel, starts: &[f64], goals: &[f64], clearance: f64) -> Result<Vec<(Motion, usize)>> {
    use rayon::prelude::*;

    if !(clearance > 0.0 && clearance <= MAX_CLEARANCE) {
        return Err(Error::InvalidInput(format!("clearance must be in (0, {MAX_CLEARANCE}] m; got {clearance}")));
    }
    let b = model.check_poses(starts)?;
    if goals.len() != starts.len() {
        return Err(Error::InvalidInput(format!("starts and goals differ in shape: {} and {} values", starts.len(), goals.len())));
    }
    model.check_poses(goals)?;
    let k = model.njoint();
    let wraps = model.continuous();
    let space = Space { lo: vec![f64::NEG_INFINITY; k], hi: vec![f64::INFINITY; k], wraps };
    let levers = Levers::of(model);
    let idx: Vec<usize> = (0..b).collect();
    let parts: Vec<Result<Vec<(Motion, usize)>>> = idx
        .par_chunks(CHUNK)
        .map_init(
            || (MotionScratch::new(model), vec![0.0; k]),
            |(ms, d), chunk| {
                chunk
                    .iter()
                    .map(|&i| {
                        let (a, g) = (&starts[i * k..(i + 1) * k], &goals[i * k..(i + 1) * k]);
                        space.delta(a, g, d);
                        let m = certify_motion(model, levers, &space, a, d, clearance, ms)
                            .map_err(|e| e.error(model, format!("motion {i}")))?;
                        Ok((m, ms.states))
                    })
                    .collect()
            },
        )
        .collect();
    Ok(first_error(parts)?.concat())
}
