//! Straight motions in joint space, certified continuously: conservative advancement.
//!
//! A motion is `q(t) = a + t·Δ`, `t ∈ [0, 1]`, with `Δ` the short arc on continuous hinges (the
//! SO(2) interpolation `joints/interpolate.rs` replays, states wrapped by `angles::wrap`). It is
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
//!    Tighter near a placed state (`Rate`): relative to `c`, a geom moves as one rigid body, so
//!    no point of it moves faster than `a = |v| + r·|ω|` (its bounding sphere's centre's velocity
//!    and its angular velocity, read off the placed frames: the joints' vectors summed, where
//!    they may cancel, rather than their lengths), and that speed grows at most at a rate `b`
//!    the levers bound, so the distance falls by at most `min(M·τ, a·τ + b·τ²/2)` within `τ` of
//!    the state.
//!    Where the state's distance is a separation along an axis (the exact bound's), the rate
//!    that way is tighter still (`axis_rates`): only the points' velocities along the axis
//!    close it, forward and backward apart, so a pair moving apart or sliding past has a small
//!    or negative rate one way.
//! 2. **What a state proves.** If the pair's distance at `t₀` is `d > need`, it stays above
//!    `need` for `|t − t₀| < τ` while the fall bound stays under `d − need`: the state's
//!    *radius* for the pair.
//! 3. **What an interval proves.** `[t₀, t₁]` is proven for the pair when `r(t₀) + r(t₁) ≥ t₁ −
//!    t₀`. Intervals that are not are halved at their midpoint, which is placed and measured for
//!    the pairs still open there only, level by level (so a collision anywhere on the motion is
//!    met early, as by the sampled check's coarse-to-fine order). The first level is the whole
//!    motion, its ends measured first ([`Order::EndFirst`]), or its two halves, the middle
//!    measured first and each end only for the pairs its half leaves open
//!    ([`Order::MiddleFirst`]: between free poses a pair the middle proves both ways, `r(½) ≥ ½`,
//!    costs one state instead of two or three).
//!
//! Distances are lower bounds, the cheapest that closes the interval: the pair's bounding
//! spheres (`model/broad.rs`), enough wherever the pair is far; else the smaller geom's sphere
//! against the larger one's bounding box (`collide::Scratch::box_gap`: a link above a board or a
//! table top, whose own sphere is far larger than its distance); else a separation along an axis from
//! the two shapes' exact support points (`collide::Scratch::pair_lower_bound`: the pair's axis
//! from the previous state or the line between the geoms, and GJK's where that cannot decide
//! or nearly closes the interval; the support point for a plane), reduced by
//! `broad::DISTANCE_SLACK` for rounding. A state where some pair is not shown above `need` ends the
//! motion: [`Motion::Blocked`] (in contact, within the clearance, or, rarely, a pair GJK found no
//! separating axis for). The halving stops when an open interval moves no joint more than
//! [`MIN_STEP`]: a motion that grazes a pair within ~`M·MIN_STEP` of `need` may be
//! [`Motion::Unproven`] though free; nothing unproven is ever called free.
//!
//! The levers take every slide within its limits: a motion with a limited slide outside them
//! is unproven, as is one whose pair depends on an unlimited slide that moves (an infinite
//! lever), and one with a joint beyond [`MAX_JOINT`].
//!
//! Every verdict, and the states placed, are a function of the motion alone (the separating
//! axes a pair remembers from state to state are forgotten at the start of each motion), so
//! they are the same on any thread.

use std::f64::consts::PI;

use crate::collision::collide::{box_sides, first_error, Scratch, Undecided};
use crate::error::{Error, Result};
use crate::joints::angles::wrap;
use crate::joints::couplings::{Couplings, FEASIBLE_TOL};
use crate::model::broad::{check_clearance, slack_above, DISTANCE_SLACK};
use crate::model::kinematics::body_poses4_wide;
use crate::model::lanes::Frames4;
use crate::model::{Apart, PairSpans, RobotModel};
use crate::planning::spans::{clear_spans, covers, has_cloud, span_need};
use nalgebra::Isometry3;

/// Radians / metres: the smallest joint move of an interval the certificate halves further.
pub const MIN_STEP: f64 = 1e-7;
/// Most states one motion may place before it is called unproven.
pub const MAX_STATES: usize = 1 << 16;
/// Radians / metres: a motion with a joint beyond this, at either end, is unproven (too far to
/// place meaningfully in floating point).
pub const MAX_JOINT: f64 = 1e6;

/// The verdict on one motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    /// Every pair stays above its `need` at every state of the motion.
    Certified,
    /// The placed state at `t` has a pair not shown above its `need` (module docs).
    Blocked(f64),
    /// Neither proven nor refuted within [`MIN_STEP`] / [`MAX_STATES`].
    Unproven,
}

/// Where a motion's proof starts (module docs, point 3); either way every pair is proven over
/// the whole motion, so the order changes what a proof costs, not what it proves (a motion at
/// the state budget aside, and which blocked state a blocked motion reports).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// The end, by the bounding spheres alone; then the start; then the end again, exactly, for
    /// the pairs still open: for a motion whose end is new (a pose someone asks about), where a
    /// motion most often collides.
    EndFirst,
    /// The middle, both ways at once; then each end for the pairs still open on its half: for a
    /// motion between poses known to be free (a planner's edge, refuted cheaply at a few states
    /// first; a timed path's chords and blends, whose ends lie on proven motions), where most
    /// pairs close from the middle with one state instead of two or three.
    MiddleFirst,
}

/// The joint space: bounds per joint and which joints wrap (continuous hinges).
#[derive(Clone, Debug)]
pub(crate) struct Space {
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
    pub wraps: Vec<bool>,
    /// The joint equalities: every placed state is projected onto them (`along`).
    pub couplings: Couplings,
}

impl Space {
    /// The model's sampling ranges (`RobotModel::sampling_ranges`) and continuous hinges.
    pub fn of(model: &RobotModel) -> Result<Space> {
        let ranges = model.sampling_ranges()?;
        Ok(Space {
            lo: ranges.iter().map(|r| r[0]).collect(),
            hi: ranges.iter().map(|r| r[1]).collect(),
            wraps: model.continuous(),
            couplings: model.couplings.clone(),
        })
    }

    /// `b − a`, the short arc on wrapping joints.
    pub fn delta(&self, a: &[f64], b: &[f64], out: &mut [f64]) {
        for k in 0..a.len() {
            let d = b[k] - a[k];
            out[k] = if self.wraps[k] { wrap(d) } else { d };
        }
    }

    /// The squared distance from `a` to `b`: the sum of the squares of `delta` (the planner's
    /// metric is its root, `plan::Tree::nearest`).
    #[inline]
    pub fn squared(&self, a: &[f64], b: &[f64]) -> f64 {
        let mut s = 0.0;
        for k in 0..a.len() {
            let d = b[k] - a[k];
            let d = if self.wraps[k] { wrap(d) } else { d };
            s += d * d;
        }
        s
    }

    /// `a + t·Δ` into `out`, wrapping joints mapped back into [-π, π), then the dependent joints
    /// recomputed from the couplings (the state the robot is in: `joints/couplings.rs`, "Motions").
    pub fn along(&self, a: &[f64], d: &[f64], t: f64, out: &mut [f64]) {
        self.place(&Line { a, delta: d }, t, out);
    }

    /// The curve's state at `t` into `out`, by `along`'s rules.
    #[inline]
    pub fn place<C: Curve>(&self, c: &C, t: f64, out: &mut [f64]) {
        for (k, ((o, &wraps), (&lo, &hi))) in out.iter_mut().zip(&self.wraps).zip(self.lo.iter().zip(&self.hi)).enumerate() {
            let v = c.at(k, t);
            *o = if wraps { wrap(v) } else { v.clamp(lo, hi) };
        }
        self.couplings.apply(out);
    }
}

/// A motion `q(t)`, `t ∈ [0, 1]`, in unwrapped joint coordinates, as the certificate reads it:
/// each state, and per joint a bound on its speed and points whose interval holds every value it
/// takes. The proof (module docs) needs only these: a pair's distance falls at most at
/// `Σ_j R_j·max_t |q̇_j(t)|`, whatever the shape of the curve.
pub(crate) trait Curve {
    /// Joint `j` at `t`, unwrapped.
    fn at(&self, j: usize, t: f64) -> f64;
    /// Joint `j`'s largest speed `max_t |q̇_j(t)|`, and its start, end and a third point whose
    /// interval holds `q_j(t)` for every `t`.
    fn hull(&self, j: usize) -> (f64, [f64; 3]);
    /// Joint `j`'s velocity `q̇_j(t)` (per unit of `t`, signed).
    fn velocity(&self, j: usize, t: f64) -> f64;
    /// A bound on joint `j`'s acceleration `|q̈_j(t)|` over the whole curve.
    fn accel(&self, j: usize) -> f64;
}

/// The straight motion `a + t·Δ`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Line<'a> {
    pub a: &'a [f64],
    pub delta: &'a [f64],
}

impl Curve for Line<'_> {
    #[inline]
    fn at(&self, j: usize, t: f64) -> f64 {
        self.a[j] + t * self.delta[j]
    }

    #[inline]
    fn hull(&self, j: usize) -> (f64, [f64; 3]) {
        let (x0, x1) = (self.a[j], self.a[j] + self.delta[j]);
        (self.delta[j].abs(), [x0, x1, x1])
    }

    #[inline]
    fn velocity(&self, j: usize, _t: f64) -> f64 {
        self.delta[j]
    }

    #[inline]
    fn accel(&self, _j: usize) -> f64 {
        0.0
    }
}

/// The quadratic Bézier `p₀ → p₁ → p₂` (`d₁ = p₁ − p₀`, `d₂ = p₂ − p₁`, short arcs):
/// `q(t) = p₀ + 2t·d₁ + t²·(d₂ − d₁)`. A trajectory's parabolic blend at a corner `p₁`
/// (constant acceleration from the velocity along `d₁` to the one along `d₂`) is one. Its speed
/// `2·((1 − t)·d₁ + t·d₂)` is largest at an end, `2·max(|d₁|, |d₂|)`, and it stays in the hull of
/// its control points.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Bezier<'a> {
    pub p0: &'a [f64],
    pub d1: &'a [f64],
    pub d2: &'a [f64],
}

impl Curve for Bezier<'_> {
    #[inline]
    fn at(&self, j: usize, t: f64) -> f64 {
        if t == 1.0 {
            // (the end bit for bit: where the next straight piece starts)
            return self.p0[j] + self.d1[j] + self.d2[j];
        }
        self.p0[j] + 2.0 * t * self.d1[j] + t * t * (self.d2[j] - self.d1[j])
    }

    #[inline]
    fn hull(&self, j: usize) -> (f64, [f64; 3]) {
        let (x0, x1) = (self.p0[j], self.p0[j] + self.d1[j]);
        (2.0 * self.d1[j].abs().max(self.d2[j].abs()), [x0, x1 + self.d2[j], x1])
    }

    #[inline]
    fn velocity(&self, j: usize, t: f64) -> f64 {
        2.0 * ((1.0 - t) * self.d1[j] + t * self.d2[j])
    }

    #[inline]
    fn accel(&self, j: usize) -> f64 {
        // (rounded up: the difference of two rounded differences)
        2.0 * (self.d2[j] - self.d1[j]).abs() * (1.0 + 1e-12)
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
    /// `npairs + 1` offsets, then every pair's chain (`chain`).
    chains: &'m [u32],
    /// Where the chains start in `chains`: `npairs + 1` (kept, not divided out of `rows` on
    /// every call: an integer division costs tens of cycles, and `chain` runs per pair per state).
    base: usize,
    /// Per pair, the geom whose branch from the world is the pair's whole chain (a geom against
    /// one the world holds still), `u32::MAX` for the others: such a pair's rates are its geom's,
    /// the same for every pair of it.
    solo: &'m [u32],
    /// Per pair, its chain's entries on each side: the last that many of the side's geom's
    /// branch (`branch`), whose state-local terms each state sums once per geom (`Axes::sums`).
    sides: &'m [[u32; 2]],
    /// `ngeom + 1` offsets, then each geom's branch from the world, top down (`branch`).
    branches: &'m [u32],
    /// Geom-major `(ngeom, K)`: a branch joint's lever to the geom (a pair's row on that side).
    reach: &'m [f64],
    /// Geom-major `(ngeom, K)`: a branch joint's lever to the geom's bounding-sphere centre.
    centre: &'m [f64],
    /// Per geom, the first geom on its body (`LeverTable::twin`).
    twin: &'m [u32],
    ngeom: usize,
}

impl<'m> Levers<'m> {
    pub(crate) fn of(model: &'m RobotModel) -> Levers<'m> {
        let t = model.lever_rows.get_or_init(|| lever_rows(model));
        Levers {
            k: model.njoint(),
            rows: &t.rows,
            chains: &t.chains,
            base: model.pairs.len() + 1,
            solo: &t.solo,
            sides: &t.sides,
            branches: &t.branches,
            reach: &t.reach,
            centre: &t.centre,
            twin: &t.twin,
            ngeom: model.geoms.len(),
        }
    }

    /// Per geom (the layout of `Axes::twist`), summed over its branch from the geom up: the
    /// chain rate's terms `|Δ_j|·R_j` (`chain`, entry `i` from branch entry `i` down to the geom)
    /// and the growth of the state-local rate (`Rate::b`, in `axes.quad`): over the side's
    /// `known` joints `m` (`Axes`), `|q̈_m|·(ρ_m + r) + |Δ_m|·(U_m·(ρ_m + r) + C_m)` (`Rate`),
    /// with `ρ_m` the joint's lever to the geom's centre, `r` the geom's bounding radius, `U_m`
    /// the speeds of the side's hinges above `m` and `C_m = Σ |Δ_i|·ρ_i` over the joints from
    /// `m` down to the geom. Summed from the geom up, each entry `x` adds its own term and, a
    /// hinge above every known joint below it, `|Δ_x|` to each of their `U`s: `|Δ_x|·Σ
    /// |Δ_m|·(ρ_m + r)` (all terms positive: no cancellation). A pair's `rate` and growth are the
    /// sums over its sides (`side_sums`; the joints below an entry on a pair's side are the
    /// branch's below it). Joints that do not move add nothing.
    ///
    /// And the state-local rate's terms of the joints it takes at their levers (`Axes::other`):
    /// `Σ |Δ_j|·R_j` over the joints that are not `known`.
    fn motion_sums(&self, model: &RobotModel, abs_delta: &[f64], axes: &mut Axes) {
        for g in 0..self.ngeom {
            let (from, to) = (self.branches[g] as usize, self.branches[g + 1] as usize);
            let base = from + g;
            let r = model.geoms[g].shape.radius;
            let (mut c, mut centre, mut b, mut w, mut other) = (0.0, 0.0, 0.0, 0.0, 0.0);
            axes.chain[base + to - from] = 0.0;
            axes.quad[base + to - from] = 0.0;
            axes.other[base + to - from] = 0.0;
            for (i, &e) in self.branch(g).iter().enumerate().rev() {
                let j = entry_joint(e);
                let d = abs_delta[j];
                if d != 0.0 {
                    c += d * self.reach[g * self.k + j];
                    if !axes.known[j] {
                        other += d * self.reach[g * self.k + j];
                    }
                    let rho = self.centre[g * self.k + j];
                    centre += d * rho;
                    if model.joints[j].hinge {
                        b += d * w;
                    }
                    if axes.known[j] {
                        b += axes.acc[j] * (rho + r) + d * centre;
                        w += d * (rho + r);
                    }
                }
                axes.chain[base + i] = c;
                axes.quad[base + i] = b;
                axes.other[base + i] = other;
            }
        }
    }

    /// Pair `p`'s sum over its sides of geom-major branch `sums` (`motion_sums`, `Axes::sums`).
    #[inline]
    fn side_sums(&self, model: &RobotModel, sums: &[f64], p: usize) -> f64 {
        let pair = &model.pairs[p];
        let [n1, n2] = self.sides[p];
        let side = |g: usize, n: u32| sums[self.branches[g + 1] as usize + g - n as usize];
        let x = if n1 > 0 { side(pair.g1, n1) } else { 0.0 };
        if n2 > 0 {
            x + side(pair.g2, n2)
        } else {
            x
        }
    }

    /// Geom `g`'s branch: the chain entries of every joint from the world down to its body,
    /// top down; a pair's side is the last `sides[p][side]` of its geom's.
    #[inline]
    fn branch(&self, g: usize) -> &'m [u32] {
        let n = self.ngeom + 1;
        &self.branches[n + self.branches[g] as usize..n + self.branches[g + 1] as usize]
    }

    /// Pair `p`'s chain: its moving joints, each `joint << 2 | TIGHT if tight | side` (side 0:
    /// the first geom's branch), each branch from the common ancestor down to its geom.
    #[inline]
    fn chain(&self, p: usize) -> &'m [u32] {
        let n = self.base;
        &self.chains[n + self.chains[p] as usize..n + self.chains[p + 1] as usize]
    }

    /// The joints pair `p`'s distance depends on, ascending, each once.
    fn joints(&self, p: usize) -> Vec<usize> {
        let mut joints: Vec<usize> = self.chain(p).iter().map(|&e| entry_joint(e)).collect();
        joints.sort_unstable();
        joints.dedup();
        joints
    }

    /// The one joint pair `p`'s distance depends on, when there is just one (`planning/spans.rs`).
    #[inline]
    fn sole_joint(&self, p: usize) -> Option<usize> {
        match self.chain(p) {
            [e] => Some(entry_joint(*e)),
            _ => None,
        }
    }

    /// Per candidate pair, the joint and the spans of `planning/spans.rs` (`RobotModel::joint_spans`),
    /// swept on first use (on the calling thread, as `fastpath::likely_pairs`). A pair its
    /// moving geom's swept ball proves clear in every configuration (`swept_ball_clear`) spans
    /// the joint's whole range without a sweep (which would find that one span, state by state).
    fn spans(&self, model: &'m RobotModel) -> &'m [PairSpans] {
        model.joint_spans.get_or_init(|| {
            let mut s = Scratch::new(model);
            let mut gaps = Gaps::of(model);
            let inherited = model.inherited.as_ref();
            let ranges = model.sampling_ranges().ok();
            let mut ball = |s: &mut Scratch, p: usize, j: usize| {
                ranges.as_ref().filter(|r| swept_ball_clear(model, *self, s, p, r, &mut gaps)).map(|r| vec![r[j]])
            };
            (0..model.pairs.len())
                .map(|p| match (inherited.and_then(|i| i.spans(p)), self.sole_joint(p)) {
                    (Some(taken), _) => taken.clone(),
                    (None, Some(j)) => {
                        (j as u32, ball(&mut s, p, j).unwrap_or_else(|| clear_spans(model, p, j, self.rows[p * self.k + j], &mut s)))
                    }
                    (None, None) => (u32::MAX, Vec::new()),
                })
                .collect()
        })
    }

    /// The pair's rate `M` (metres per unit of `t`) for joint moves `|Δ|`; an infinite lever
    /// counts only for a joint that moves. (Over the chain: the row is 0 elsewhere. Pair by
    /// pair: what `motion_sums` sums once per geom, kept for the tests.)
    #[cfg(test)]
    fn rate(&self, pair: usize, abs_delta: &[f64]) -> f64 {
        let row = &self.rows[pair * self.k..(pair + 1) * self.k];
        self.chain(pair).iter().map(|&e| entry_joint(e)).filter(|&j| abs_delta[j] != 0.0).map(|j| row[j] * abs_delta[j]).sum()
    }
}

/// The lever table of `Levers`: the `(npairs, K)` rows, the pairs' chains, their `solo`
/// geoms and sides, and each geom's branch and levers.
fn lever_rows(model: &RobotModel) -> crate::model::LeverTable {
    let k = model.njoint();
    let ngeom = model.geoms.len();
    let mut rows = vec![0.0; model.pairs.len() * k];
    let mut offsets = vec![0u32];
    let mut entries = Vec::new();
    let mut solo = Vec::with_capacity(model.pairs.len());
    let mut sides = Vec::with_capacity(model.pairs.len());
    // (a joint's reach to a geom, `joint_reach`, is the joint's and the geom's alone: computed
    // once per geom and joint of its branch, before the pairs, which read them; a scene's
    // obstacles pair with every link)
    let mut reach = vec![f64::NAN; k * ngeom];
    let mut centre = vec![f64::NAN; k * ngeom];
    let mut walks = vec![None; k * model.body_parent.len()];
    // Each body and its ancestors, up to the world.
    let ups: Vec<Vec<usize>> = (0..model.body_parent.len())
        .map(|mut b| {
            let mut out = vec![b];
            while b != 0 {
                b = model.body_parent[b];
                out.push(b);
            }
            out
        })
        .collect();
    // Each geom's branch from the world, top down: a pair's side is its last entries (the
    // chain from the common ancestor down to the geom, built the same way); and its levers.
    let mut branches = vec![0u32];
    let mut branch = Vec::new();
    for g in 0..ngeom {
        let up = &ups[model.geoms[g].body];
        for &b in up.iter().rev() {
            let (j0, j1) = model.body_joints[b];
            for j in j0..j1 {
                branch.push((j as u32) << 2 | if tight(model, j) { TIGHT } else { 0 });
                (reach[g * k + j], centre[g * k + j]) = joint_reach(model, j, g, up, &mut walks);
            }
        }
        branches.push(branch.len() as u32);
    }
    branches.extend(branch);
    // Each body pair's chain entries, common ancestor, first side's entry count and whether
    // one side alone moves, once (`memo[start..end]`): a scene's obstacles share the world's,
    // and a link's geoms their body's.
    // (by the body pairs met, each first body's few in a list: not a table of every body
    // pair, which grows with the square of the bodies, nor a hash per pair)
    #[derive(Clone, Copy)]
    struct Met {
        start: usize,
        end: usize,
        common: usize,
        first: u32,
        one_side: Option<u32>,
    }
    let mut by_bodies: Vec<Vec<(usize, Met)>> = vec![Vec::new(); model.body_parent.len()];
    let mut memo = Vec::new();
    for (p, pair) in model.pairs.iter().enumerate() {
        let (b1, b2) = (model.geoms[pair.g1].body, model.geoms[pair.g2].body);
        let met = by_bodies[b1].iter().find(|(b, _)| *b == b2).map(|m| m.1);
        let met = met.unwrap_or_else(|| {
            let (up1, up2) = (&ups[b1], &ups[b2]);
            let common = *up1.iter().find(|b| up2.contains(b)).expect("the world is a common ancestor");
            let start = memo.len();
            for (side, up) in [up1, up2].into_iter().enumerate() {
                let below = up.iter().position(|&b| b == common).expect("the common ancestor is an ancestor");
                for &b in up[..below].iter().rev() {
                    let (j0, j1) = model.body_joints[b];
                    memo.extend((j0..j1).map(|j| (j as u32) << 2 | if tight(model, j) { TIGHT } else { 0 } | side as u32));
                }
            }
            let chain = &memo[start..];
            let first = chain.iter().filter(|&&e| e & SIDE == 0).count() as u32;
            let one_side = chain.first().filter(|&&e| chain.iter().all(|&c| c & SIDE == e & SIDE)).map(|&e| e & SIDE);
            let met = Met { start, end: memo.len(), common, first, one_side };
            by_bodies[b1].push((b2, met));
            met
        });
        let chain = &memo[met.start..met.end];
        let row = &mut rows[p * k..(p + 1) * k];
        for &e in chain {
            let (j, g) = (entry_joint(e), if e & SIDE == 0 { pair.g1 } else { pair.g2 });
            // (each joint is on one side only: one term per entry of the row)
            row[j] += reach[g * k + j];
        }
        entries.extend_from_slice(chain);
        offsets.push(entries.len() as u32);
        sides.push([met.first, chain.len() as u32 - met.first]);
        // (one side's entries only, and that side's whole branch from the world: the chain,
        // and the rows over it, are its geom's alone)
        solo.push(match (met.common, met.one_side) {
            (0, Some(side)) => (if side == 0 { pair.g1 } else { pair.g2 }) as u32,
            _ => u32::MAX,
        });
    }
    offsets.extend(entries);
    let mut first = vec![u32::MAX; model.body_parent.len()];
    let twin = (0..ngeom)
        .map(|g| {
            let f = &mut first[model.geoms[g].body];
            if *f == u32::MAX {
                *f = g as u32;
            }
            *f
        })
        .collect();
    crate::model::LeverTable { rows, chains: offsets, solo, sides, branches, reach, centre, twin }
}

/// A chain entry's bits: the geom's side (0: the first geom's branch), and whether the joint is
/// `tight`; the joint is the rest (`entry_joint`).
const SIDE: u32 = 1;
const TIGHT: u32 = 2;

#[inline]
fn entry_joint(e: u32) -> usize {
    (e >> 2) as usize
}

/// Whether joint `j`'s world axis and anchor can be read off its body's placed frame: a hinge
/// that is the last joint of its body (a later joint on the same body would move them).
#[inline]
fn tight(model: &RobotModel, j: usize) -> bool {
    let jnt = &model.joints[j];
    jnt.hinge && j + 1 == model.body_joints[jnt.body].1
}

/// How fast a pair's distance can shrink, per unit of `t`, `τ` away from a placed state: at most
/// `chain` (the configuration-free levers), and at most `a + b·τ`. At the state, relative to the
/// pair's common ancestor, each side's geom moves as one rigid body: no point of it moves faster
/// than `|v| + r·|ω|` (`side_sum`), the joints' terms summed as vectors. Along the motion, hinge
/// `m`'s terms `q̇_m·w_m`, `w_m = u_m × (c − p_m)`, and `r·q̇_m·u_m` change in two ways: the
/// hinges above `m` (speeds `U_m`) turn `u_m`, `p_m` and `c` together as one rigid body, so `w_m`
/// turns with them, `|ẇ_m| ≤ U_m·|w_m|`, and `|u̇_m| ≤ U_m`; the joints from `m` down move `c`
/// alone, at most at `C_m = Σ |q̇_i|·ρ_i` (`ρ` the levers to the centre). With `|w_m| ≤ ρ_m`,
/// the terms grow at most at `b`'s terms `|q̈_m|·(ρ_m + r) + |q̇_m|·(U_m·(ρ_m + r) + C_m)`
/// (`Levers::motion_sums`). So the distance falls by at most `drop(τ) = min(chain·τ, a·τ +
/// b·τ²/2)` within `τ` of the state.
#[derive(Clone, Copy, Debug)]
struct Rate {
    chain: f64,
    a: f64,
    b: f64,
}

impl Rate {
    fn of_chain(chain: f64) -> Rate {
        Rate { chain, a: chain, b: 0.0 }
    }

    #[inline]
    fn drop(&self, tau: f64) -> f64 {
        let tau = tau.max(0.0);
        (self.chain * tau).min(self.a * tau + 0.5 * self.b * tau * tau)
    }

    /// The largest `τ` with `drop(τ) <= slack` (slack > 0), in either form.
    #[inline]
    fn reach(&self, slack: f64) -> f64 {
        if self.chain <= 0.0 {
            return f64::INFINITY;
        }
        let linear = slack / self.chain;
        if self.b == 0.0 && self.a == self.chain {
            // (the chain rate alone: the quadratic form is `2s / (c + sqrt(c²))`, which is `s / c`
            // bit for bit for a rate and slack in the normal range, the square root of a rounded
            // square being exact; below ~1e-154 or above ~1e307, where the square or `2s` leaves
            // the range, the quadratic form read past `s / c`, and `s / c` is the right answer)
            return linear;
        }
        // (the root of `a·τ + b·τ²/2 = slack` in the form without cancellation: `a` is negative
        // where the pair moves apart along the axis its rate was taken on, `axis_rates`; infinite
        // where it never closes, `b = 0` with `a ≤ 0`)
        let root = (self.a * self.a + 2.0 * self.b * slack).sqrt();
        let quadratic = if self.a >= 0.0 { 2.0 * slack / (self.a + root) } else { (root - self.a) / self.b };
        if quadratic.is_nan() {
            linear
        } else {
            linear.max(quadratic)
        }
    }
}

/// A `tight` joint's world anchor `p` and axis `u` in the state placed with `stamp` (0: none),
/// with `u × p` and the rounding scale `1 + |p|₁` (`sum_body`).
#[derive(Clone, Copy, Default)]
struct Placed {
    stamp: u32,
    u: nalgebra::Vector3<f64>,
    u_p: nalgebra::Vector3<f64>,
    scale: f64,
}

/// World anchors and axes of the `tight` joints, each computed on first use in a placed state
/// (`Placed`).
/// And each geom's state-local terms along its branch, summed from the geom up (`twist`): a
/// pair's side is a suffix of its geom's branch, so every pair of a geom reads its side's sum
/// off the same array (a Panda's 272 pairs over 26 geoms: one sum per geom and state, not one
/// per pair). (A stamp beside its value: one bounds check reads both.)
struct Axes {
    joint: Vec<Placed>,
    /// Per geom, the stamp of the state its `twist` (a body's first geom: `Levers::twin`) and
    /// its `bound` belong to (0: none).
    summed: Vec<u32>,
    /// Geom `g`'s suffix sums at `branches[g] + g ..= branches[g + 1] + g` (`Levers::branch`),
    /// kept for the first geom of each body: entry `i` sums the branch's terms from `i` down to
    /// the body (`sum_body`: `ω`, `Σ q̇_m·u_m × p_m` and two rounding scales).
    twist: Vec<[f64; 8]>,
    /// Per geom, the same layout: the state-local terms of the side from that entry down
    /// (`SideRate`), computed on first read in a state.
    bound: Vec<SideRate>,
    /// The motion's chain-rate sums per geom (`Levers::motion_sums`), the layout of `twist`.
    chain: Vec<f64>,
    /// The motion's sums of the terms of the joints that are not `known`, the same layout.
    other: Vec<f64>,
    /// The motion's growth sums per geom (`Levers::motion_sums`), the layout of `twist`.
    quad: Vec<f64>,
    /// Per joint, whether the state-local rate takes its signed velocity (`vel`) at the state: a
    /// `tight` hinge that no coupling drives and whose values the motion never clamps (its
    /// velocity is then the curve's); the others count at their lever times their speed.
    known: Vec<bool>,
    /// Per joint, the curve's velocity at the placed state (`Curve::velocity`), and a bound on
    /// its acceleration over the motion (`Curve::accel`).
    vel: Vec<f64>,
    acc: Vec<f64>,
    /// (tests) The placed state's `t`, and every radius of the motion: pair, `t`, `[back, fwd]`
    /// (0 for a way not asked for; spanned pairs infinite forward from 0).
    #[cfg(test)]
    t: f64,
    #[cfg(test)]
    covers: Vec<(usize, f64, [f64; 2])>,
}

impl Axes {
    fn new(model: &RobotModel) -> Self {
        let levers = Levers::of(model);
        let ngeom = model.geoms.len();
        Axes {
            joint: vec![Placed::default(); model.njoint()],
            summed: vec![0; ngeom],
            twist: vec![[0.0; 8]; levers.branches[ngeom] as usize + ngeom],
            bound: vec![SideRate::UNREAD; levers.branches[ngeom] as usize + ngeom],
            chain: vec![0.0; levers.branches[ngeom] as usize + ngeom],
            other: vec![0.0; levers.branches[ngeom] as usize + ngeom],
            quad: vec![0.0; levers.branches[ngeom] as usize + ngeom],
            known: vec![false; model.njoint()],
            vel: vec![0.0; model.njoint()],
            acc: vec![0.0; model.njoint()],
            #[cfg(test)]
            t: 0.0,
            #[cfg(test)]
            covers: Vec::new(),
        }
    }

    /// The motion's `known` joints and accelerations (`curve`'s, each joint sweeping
    /// `lo..=hi`, its speed bound `abs_delta`), in `space`.
    fn motion<C: Curve>(&mut self, model: &RobotModel, space: &Space, curve: &C, lo: &[f64], hi: &[f64]) {
        for j in 0..self.known.len() {
            let free = space.wraps[j] || (space.lo[j] <= lo[j] && hi[j] <= space.hi[j]);
            self.known[j] = free && tight(model, j);
            self.acc[j] = curve.accel(j);
        }
        for c in space.couplings.rows() {
            self.known[c.dep as usize] = false;
        }
    }

    /// The curve's velocities at `t`, the state about to be placed.
    #[inline]
    fn at<C: Curve>(&mut self, curve: &C, t: f64) {
        for (j, v) in self.vel.iter_mut().enumerate() {
            *v = curve.velocity(j, t);
        }
        #[cfg(test)]
        {
            self.t = t;
        }
    }

    /// Forgets every state's values (a new motion).
    fn forget(&mut self) {
        self.joint.iter_mut().for_each(|x| x.stamp = 0);
        self.summed.fill(0);
        self.bound.iter_mut().for_each(|x| x.stamp = 0);
        #[cfg(test)]
        self.covers.clear();
    }
}

/// One side of a pair in a placed state (`side_sum`): its geom's sphere-centre velocity `v` and
/// angular velocity times its bounding radius `wr` (relative to the top of the side, in world
/// axes), and the side's bound without a direction, `a = (|v| + |wr|)·(1 + 1e-9) + extra`, with
/// `extra` the terms bounded without a direction (the joints taken at their levers) and the
/// rounding allowance.
#[derive(Clone, Copy, Debug)]
struct SideRate {
    v: nalgebra::Vector3<f64>,
    wr: nalgebra::Vector3<f64>,
    a: f64,
    /// `extra` and the rounding allowance of a rate along an axis, `1e-9·(|v|₁ + |wr|₁)`.
    extra_axis: f64,
    /// The state these terms belong to (0: none).
    stamp: u32,
}

impl SideRate {
    const UNREAD: SideRate = SideRate {
        v: nalgebra::Vector3::new(0.0, 0.0, 0.0),
        wr: nalgebra::Vector3::new(0.0, 0.0, 0.0),
        a: f64::NAN,
        extra_axis: 0.0,
        stamp: 0,
    };
}

/// The state-local rate `a` of pair `p` (`Rate`) in the state placed in `s`, in no direction:
/// the sum over its sides of their geoms' bounds (`side_sum`).
#[inline]
fn local_rate(model: &RobotModel, levers: Levers, s: &Scratch, axes: &mut Axes, p: usize) -> f64 {
    let pair = &model.pairs[p];
    let [n1, n2] = levers.sides[p];
    // (a scene pair's other side is the world's: no term)
    let a = if n1 > 0 { side_sum(model, levers, s, axes, pair.g1, n1 as usize).a } else { 0.0 };
    if n2 > 0 {
        a + side_sum(model, levers, s, axes, pair.g2, n2 as usize).a
    } else {
        a
    }
}

/// The state-local rates `a` of pair `p` in the state placed in `s`, `[back, fwd]` along the
/// motion, for a separation along the unit axis `n` (world, from the pair's first geom `A`
/// toward its second `B`; zero: none, then both are `plain`, the pair's `local_rate`).
///
/// Directional advancement: at the state, `B` lies beyond `A` along `n` by the separation.
/// Hold that axis fixed in the frame of the pair's common ancestor (the top of both sides,
/// where every term of `side_sum` is measured). Going forward, `A`'s points close along `n` at
/// most at `n·v_A + r_A·|n × ω_A|` (a point `c + y`, `|y| ≤ r`, moves at `v + ω × y`, and
/// `n·(ω × y) = y·(n × ω)`), `B`'s at `−n·v_B + r_B·|n × ω_B|`; backward, the velocities change
/// sign. While the two stay apart along `n`, their distance is at least their separation along
/// it, which falls at most at the sum. Each side's terms grow at most as its bound without a
/// direction does (`|n·Δv| ≤ |Δv|`, and `|n × ω|` is 1-Lipschitz in `ω`), so `Rate::b` is the
/// same. A pair moving apart along `n` has a negative rate that way. The rounding allowance is
/// `1e-9` of `|v|₁ + |wr|₁` per side besides its `extra`; each rate is at most `plain`.
fn axis_rates(
    model: &RobotModel,
    levers: Levers,
    s: &Scratch,
    axes: &mut Axes,
    p: usize,
    n: &nalgebra::Vector3<f64>,
    plain: f64,
) -> [f64; 2] {
    if *n == nalgebra::Vector3::zeros() {
        return [plain, plain];
    }
    let pair = &model.pairs[p];
    let [n1, n2] = levers.sides[p];
    let (mut along, mut both) = (0.0, 0.0);
    for (g, len, sign) in [(pair.g1, n1, 1.0), (pair.g2, n2, -1.0)] {
        if len == 0 {
            // (a scene pair's other side is the world's: no term)
            continue;
        }
        let side = side_sum(model, levers, s, axes, g, len as usize);
        along += sign * n.dot(&side.v);
        both += n.cross(&side.wr).norm() + side.extra_axis;
    }
    [(both - along).min(plain), (both + along).min(plain)]
}

/// How fast any point of geom `g` moves relative to the top of the last `n` entries of its
/// branch (a pair's side), in the placed state: relative to there the geom moves as one rigid
/// body with angular velocity `ω = Σ_m q̇_m·u_m` and its sphere's centre `c` at `v = Σ_m q̇_m·u_m
/// × (c − p_m) = ω × c − Σ_m q̇_m·u_m × p_m` (hinge `m`: axis `u_m`, anchor `p_m`, placed), so no
/// point of it moves faster than `|v| + r·|ω|` (`SideRate`). Joints whose signed velocity is not
/// taken (`Axes::known`) add `|Δ_j|·R_j` instead (`Axes::other`). The sums `ω` and `Σ q̇_m·u_m ×
/// p_m` are the body's, summed once per state for every geom on it (`Levers::twin`,
/// `sum_body`); a rounding allowance of `1e-9` of `Σ |q̇_m|·(1 + |p_m|₁ + |c|₁)` and of the
/// side's `Σ |Δ_j|·R_j` is added (the vector sums may cancel, and `ω × c` and the second sum
/// nearly cancel where `c` is far from the origin). Each side's terms are computed on its first
/// read in the state.
#[inline]
fn side_sum(model: &RobotModel, levers: Levers, s: &Scratch, axes: &mut Axes, g: usize, n: usize) -> SideRate {
    let state = s.pose_stamp();
    let from = levers.branches[g] as usize;
    let len = levers.branches[g + 1] as usize - from;
    let at = from + g + len - n;
    if axes.bound[at].stamp == state {
        return axes.bound[at];
    }
    let h = levers.twin[g] as usize;
    if axes.summed[h] != state {
        axes.summed[h] = state;
        sum_body(model, levers, s, axes, h, state);
    }
    let t = &axes.twist[levers.branches[h] as usize + h + len - n];
    let omega = nalgebra::Vector3::new(t[0], t[1], t[2]);
    let c = model.broad.sphere_centre(&s.broad, g);
    let v = omega.cross(&c) - nalgebra::Vector3::new(t[3], t[4], t[5]);
    let wr = omega * model.geoms[g].shape.radius;
    let far = c.x.abs() + c.y.abs() + c.z.abs();
    // (1e-9 relative: rounding of the placed frames and of the products)
    let extra = axes.other[at] + 1e-9 * (axes.chain[at] + t[6] + far * t[7]);
    let l1 = |x: &nalgebra::Vector3<f64>| x.x.abs() + x.y.abs() + x.z.abs();
    let side =
        SideRate { v, wr, a: (v.norm() + wr.norm()) * (1.0 + 1e-9) + extra, extra_axis: extra + 1e-9 * (l1(&v) + l1(&wr)), stamp: state };
    axes.bound[at] = side;
    side
}

/// The body terms of `side_sum` for geom `h`'s body in the placed state `state`, summed over its
/// branch from the body up (`Axes::twist`): per entry, `ω`, `Σ q̇_m·u_m × p_m` and the rounding
/// scales `Σ |q̇_m|·(1 + |p_m|₁)` and `Σ |q̇_m|`, over the `known` joints from that entry down.
fn sum_body(model: &RobotModel, levers: Levers, s: &Scratch, axes: &mut Axes, h: usize, state: u32) {
    let base = levers.branches[h] as usize + h;
    let (mut omega, mut m, mut scale, mut speeds) = (nalgebra::Vector3::zeros(), nalgebra::Vector3::zeros(), 0.0, 0.0);
    for (i, &e) in levers.branch(h).iter().enumerate().rev() {
        let j = entry_joint(e);
        let w = axes.vel[j];
        if axes.known[j] && w != 0.0 {
            let joint = &mut axes.joint[j];
            if joint.stamp != state {
                let jnt = &model.joints[j];
                let x = s.body(jnt.body);
                let (p, u) = ((x * nalgebra::Point3::from(jnt.anchor)).coords, x.rotation * jnt.axis.into_inner());
                *joint = Placed { stamp: state, u, u_p: u.cross(&p), scale: 1.0 + p.x.abs() + p.y.abs() + p.z.abs() };
            }
            omega += joint.u * w;
            m += joint.u_p * w;
            scale += w.abs() * joint.scale;
            speeds += w.abs();
        }
        axes.twist[base + i] = [omega.x, omega.y, omega.z, m.x, m.y, m.z, scale, speeds];
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
/// its anchor to any point of the geom in any configuration. And the same bound to the geom's
/// bounding-sphere centre (the lever without the sphere's radius; 1 for a slide).
///
/// The walk keeps a point `π` fixed in the current frame and a bound `cost ≥ |p_j − π|` (world):
/// each later hinge (anchor `α`, fixed while it turns) adds `|π − α|` and moves `π` to `α`; each
/// later slide adds its largest displacement; a body's fixed offset maps `π` into the child's
/// coordinates exactly. At the geom: `|π − centre| + radius`, its bounding sphere. The walk is
/// the joint's and the geom's body's alone: `walks` keeps it per body and joint (`(K · nbody)`,
/// None until walked), for every geom on that body.
fn joint_reach(model: &RobotModel, j: usize, g: usize, up: &[usize], walks: &mut [Option<(nalgebra::Vector3<f64>, f64)>]) -> (f64, f64) {
    let jnt = &model.joints[j];
    if !jnt.hinge {
        return (1.0, 1.0);
    }
    let body = model.geoms[g].body;
    let (pi, cost) = *walks[body * model.njoint() + j].get_or_insert_with(|| {
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
        (pi, cost)
    });
    let geom = &model.geoms[g];
    let centre = (geom.local * nalgebra::Point3::from(geom.shape.obb_center)).coords;
    // (1e-9 relative: rounding of the offsets, far below any distance's own slack)
    let to_centre = cost + (pi - centre).norm();
    ((to_centre + geom.shape.radius) * (1.0 + 1e-9), to_centre * (1.0 + 1e-9))
}

/// One open pair on an interval: its rate and its radii at the two ends.
#[derive(Clone, Copy, Debug)]
struct Open {
    pair: u32,
    r0: f64,
    r1: f64,
}

/// A worker's buffers of the certificate (one motion at a time).
pub struct MotionScratch {
    /// The model they are sized for (`RobotModel::id`).
    model: u64,
    pub(crate) scratch: Scratch,
    abs_delta: Vec<f64>,
    /// Per joint, the interval it sweeps along the motion.
    lo: Vec<f64>,
    hi: Vec<f64>,
    rates: Vec<f64>,
    /// Per geom, the motion's chain-rate sums over its branch (`Levers::motion_sums`).
    quads: Vec<f64>,
    axes: Axes,
    q: Vec<f64>,
    radius1: Vec<f64>,
    open: Vec<Open>,
    next: Vec<Open>,
    /// The open pairs of a level state and their radii there, `[back, fwd]`.
    mid: Vec<(Open, [f64; 2])>,
    /// Four level states' body frames, placed at once (`kinematics::body_poses4_wide`).
    lanes: Lanes,
    /// States placed by the last call.
    pub states: usize,
    /// Per pair, whether the motion's sweep lies inside one of its spans or its proven box.
    spanned: Vec<bool>,
    /// The pairs that have a span or a proven box (`provable_pairs`), once per buffer.
    provable: Option<Vec<u32>>,
}

/// The body frames of four states of one level (`certify_curve`), the level's intervals
/// `from..from + 4` in order (lanes past the level's end repeat its last state), placed in four
/// lanes at once: `body_poses`' bit for bit, so a state placed from them is the state placed
/// alone (`Scratch::place_pairs_from`). A quarter of the forward kinematics' cost a state where a
/// level holds two or more intervals.
struct Lanes {
    room: Frames4,
    frames: [Vec<Isometry3<f64>>; 4],
    qs: [Vec<f64>; 4],
    /// The level's interval in lane 0, `None` where this level has none placed.
    from: Option<usize>,
}

impl Lanes {
    fn new(model: &RobotModel) -> Self {
        Lanes {
            room: Frames4::default(),
            frames: std::array::from_fn(|_| vec![Isometry3::identity(); model.nbody()]),
            qs: std::array::from_fn(|_| vec![0.0; model.njoint()]),
            from: None,
        }
    }

    /// Places the states at `ts` (four, of `curve`, as `Space::place` places them) in the lanes,
    /// for the level's intervals from `from` on.
    fn place<C: Curve>(&mut self, model: &RobotModel, space: &Space, curve: &C, ts: [f64; 4], from: usize) {
        for (q, t) in self.qs.iter_mut().zip(ts) {
            space.place(curve, t, q);
        }
        let [f0, f1, f2, f3] = &mut self.frames;
        let [q0, q1, q2, q3] = &self.qs;
        body_poses4_wide(model, [q0, q1, q2, q3], [f0, f1, f2, f3], &mut self.room);
        self.from = Some(from);
    }

    /// The frames of the level's interval `i`, where the lanes hold them.
    fn of(&self, i: usize) -> Option<&[Isometry3<f64>]> {
        let from = self.from?;
        (from..from + 4).contains(&i).then(|| &self.frames[i - from][..])
    }
}

impl MotionScratch {
    pub fn new(model: &RobotModel) -> Self {
        MotionScratch {
            model: model.id,
            scratch: Scratch::new(model),
            abs_delta: vec![0.0; model.njoint()],
            lo: vec![0.0; model.njoint()],
            hi: vec![0.0; model.njoint()],
            rates: vec![0.0; model.pairs.len()],
            quads: vec![0.0; model.pairs.len()],
            axes: Axes::new(model),
            q: vec![0.0; model.njoint()],
            radius1: vec![0.0; model.pairs.len()],
            open: Vec::new(),
            next: Vec::new(),
            mid: Vec::new(),
            lanes: Lanes::new(model),
            states: 0,
            spanned: Vec::new(),
            provable: None,
        }
    }
}

/// Buffers the sections' workers gave back (`Spare`), the last one first: the next section's
/// workers, of this call or the next on the same model, take them instead of making new ones
/// (~30 k instructions, each worker's first item, several times a timed path). Not
/// thread-locals: this library's sit in the process's static TLS block (`threads`).
static SPARES: std::sync::Mutex<Vec<MotionScratch>> = std::sync::Mutex::new(Vec::new());

/// The most buffers `SPARES` keeps (a section's workers, a few calls at once).
const MAX_SPARES: usize = 8;

/// A worker's buffers for one section: spare ones made for the same model (else new), given
/// back when dropped. Each motion forgets what its buffers saw before (`certify_curve`), so
/// whose they were changes no verdict.
pub(crate) struct Spare(Option<MotionScratch>);

impl Spare {
    pub(crate) fn take(model: &RobotModel) -> Spare {
        let mut spares = SPARES.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        // (buffers of another model are dropped: the newest model is the one in use)
        spares.retain(|ms| ms.model == model.id);
        Spare(Some(spares.pop().unwrap_or_else(|| MotionScratch::new(model))))
    }
}

impl std::ops::Deref for Spare {
    type Target = MotionScratch;
    fn deref(&self) -> &MotionScratch {
        self.0.as_ref().expect("held until dropped")
    }
}

impl std::ops::DerefMut for Spare {
    fn deref_mut(&mut self) -> &mut MotionScratch {
        self.0.as_mut().expect("held until dropped")
    }
}

impl Drop for Spare {
    fn drop(&mut self) {
        let mut spares = SPARES.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if spares.len() < MAX_SPARES {
            spares.extend(self.0.take());
        }
    }
}

/// Why a measured pair ends the motion.
enum Stop {
    Blocked,
    Undecided(Undecided),
}

/// What `radius` needs besides the pair and the placed state: the model and the motion.
struct At<'a, 'm> {
    model: &'m RobotModel,
    levers: Levers<'m>,
    axes: &'a mut Axes,
}

/// The radii (in `t`, `[back, fwd]`: before and after the state along the motion) of pair `k`
/// (chain rate `chain`, growth `quad`) in the placed state, for an interval end whose
/// neighbours need `cover` of it each way (`NEG_INFINITY`: nothing that way, and no radius that
/// way is to be read): the bounding spheres' radii when they give the whole cover, at the chain
/// rate or the state-local one (`Rate`, `local_rate`), or the smaller sphere against the larger
/// box (`Scratch::box_gap`) when it gives the whole cover, or when a closer measurement could not
/// plausibly give even the smaller cover (then the caller halves the interval, cheaper than
/// measuring); else the separation-axis or GJK bound (`Scratch::pair_lower_bound`) with the
/// state-local rates along its own axis, each way (`axis_rates`, `Scratch::bound_axis`).
/// `Err(Blocked)` when the pair is not shown above its need. (Which bound is taken is a matter
/// of cost only: each is a lower bound. Always inlined: at each call site the ways not asked
/// for fold away.)
#[inline(always)]
fn radius(
    at: &mut At,
    s: &mut Scratch,
    k: usize,
    chain: f64,
    quad: &mut f64,
    need: f64,
    cover: [f64; 2],
) -> std::result::Result<[f64; 2], Stop> {
    let r = measure(at, s, k, chain, quad, need, cover);
    #[cfg(test)]
    if let Ok(r) = r {
        let asked = cover.map(|c| c > f64::NEG_INFINITY);
        at.axes.covers.push((k, at.axes.t, [0, 1].map(|w| if asked[w] { r[w] } else { 0.0 })));
    }
    r
}

/// `radius`'s measurement (the tests record what it gives).
#[inline(always)]
fn measure(
    at: &mut At,
    s: &mut Scratch,
    k: usize,
    chain: f64,
    quad: &mut f64,
    need: f64,
    cover: [f64; 2],
) -> std::result::Result<[f64; 2], Stop> {
    let model = at.model;
    let (gap, reach) = model.broad.sphere_gap(&s.broad, k, &model.geoms);
    let gap = gap - need;
    let plain = Rate::of_chain(chain);
    let most = cover[0].max(cover[1]);
    if gap > 0.0 && gap >= plain.drop(most) {
        let r = plain.reach(gap);
        return Ok([r, r]);
    }
    let mut rate = plain;
    if chain > 0.0 {
        // (the growth of the rate, read off its geoms' sums on the pair's first use in the motion)
        if quad.is_nan() {
            *quad = at.levers.side_sums(model, &at.axes.quad, k);
        }
        rate = Rate { chain, a: local_rate(model, at.levers, s, at.axes, k), b: *quad };
        if gap > 0.0 && gap >= rate.drop(most) {
            let r = rate.reach(gap);
            return Ok([r, r]);
        }
    }
    // The smaller geom's sphere against the larger one's box (a link above a board), where it
    // may give the cover: it is at most the sphere's distance from the ball the box holds about
    // its centre, `gap + radius − min half extent` of the larger geom.
    let drop = rate.drop(most);
    let mut best = gap;
    if gap + box_room(model, k) >= drop {
        let boxed = s.box_gap(model, k) - need;
        if boxed > 0.0 && boxed >= drop {
            let r = rate.reach(boxed);
            return Ok([r, r]);
        }
        best = best.max(boxed);
    }
    // (only the ways asked for: at an end of the motion, one)
    let asked = cover.map(|c| c > f64::NEG_INFINITY);
    let least = match asked {
        [true, true] => cover[0].min(cover[1]),
        _ => most,
    };
    if best > 0.0 && gap + reach < rate.drop(least) {
        let r = rate.reach(best);
        return Ok([r, r]);
    }
    let want = need + drop;
    let d = s
        .pair_lower_bound(
            model,
            k,
            want * (1.0 + DISTANCE_SLACK) + DISTANCE_SLACK,
            need * (1.0 + 2.0 * DISTANCE_SLACK) + 2.0 * DISTANCE_SLACK,
        )
        .map_err(Stop::Undecided)?;
    let slack = slack_above(d, need);
    if slack.is_nan() || slack <= 0.0 {
        return Err(Stop::Blocked);
    }
    let by_spheres = if best > 0.0 { rate.reach(best) } else { 0.0 };
    let exact = if chain > 0.0 {
        let axis = s.bound_axis;
        axis_rates(model, at.levers, s, at.axes, k, &axis, rate.a).map(|a| Rate { a, ..rate })
    } else {
        [rate; 2]
    };
    Ok(std::array::from_fn(|w| if asked[w] { exact[w].reach(slack).max(by_spheres) } else { f64::NAN }))
}

/// Whether pair `p` is proven at `need` over a motion's sweep (per joint, `lo..hi`) by a span of
/// its one joint (`planning/spans.rs`, proven at a need at least `need`) or by its proven box
/// (`prove_apart`): `certify_curve` then skips it.
#[inline(always)]
fn spanned_over(model: &RobotModel, spans: &[PairSpans], apart: &[Apart], p: usize, need: f64, lo: &[f64], hi: &[f64]) -> bool {
    let (j, sp) = &spans[p];
    need <= span_need(model, p)
        && ((*j != u32::MAX && covers(sp, lo[*j as usize], hi[*j as usize])) || apart.get(p).is_some_and(|a| a.covers(lo, hi)))
}

/// The pairs `spanned_over` can hold for: those with a span of their one joint or a proven box
/// (`Apart::covers` holds for no motion without one). A function of the model once
/// `prove_apart` has run.
fn provable_pairs(model: &RobotModel, spans: &[PairSpans], apart: &[Apart]) -> Vec<u32> {
    (0..model.pairs.len())
        .filter(|&p| (spans[p].0 != u32::MAX && !spans[p].1.is_empty()) || apart.get(p).is_some_and(Apart::some))
        .map(|p| p as u32)
        .collect()
}

/// How much more than the spheres' gap the box bound (`Scratch::box_gap`) of pair `k` can give:
/// the larger geom's radius less its smallest half extent (its box holds a ball that large
/// about the sphere's centre, which no point outside the box is farther from than from the box).
#[inline]
fn box_room(model: &RobotModel, k: usize) -> f64 {
    let held = &model.geoms[box_sides(model, k).1].shape;
    held.radius - held.obb_half.min()
}

/// Whether the motion `a → a + Δ` is certified (module docs) with every pair above
/// `max(margin, clearance)` metres; `Err` for a pair the narrow phase cannot measure.
/// `space` wraps and clamps the states as the planner's do; the proof starts where `order` says.
#[allow(clippy::too_many_arguments)]
pub(crate) fn certify_motion(
    model: &RobotModel,
    levers: Levers,
    space: &Space,
    a: &[f64],
    delta: &[f64],
    clearance: f64,
    order: Order,
    ms: &mut MotionScratch,
) -> std::result::Result<Motion, Undecided> {
    certify_curve(model, levers, space, &Line { a, delta }, clearance, order, ms)
}

/// Whether the motion `curve` is certified, as `certify_motion` (the speeds and swept intervals
/// are the curve's, `Curve::hull`; a blend's proof is a straight motion's).
pub(crate) fn certify_curve<C: Curve>(
    model: &RobotModel,
    levers: Levers,
    space: &Space,
    curve: &C,
    clearance: f64,
    order: Order,
    ms: &mut MotionScratch,
) -> std::result::Result<Motion, Undecided> {
    let k = model.njoint();
    ms.states = 0;
    // Each joint's speed (per unit of `t`) and the interval it sweeps; the couplings' dependent
    // joints follow their independent ones (`Couplings::speeds`). A motion too large to place
    // (a joint beyond ±`MAX_JOINT`) proves nothing.
    for j in 0..k {
        let (speed, h) = curve.hull(j);
        if !h.iter().all(|x| x.abs() <= MAX_JOINT) {
            return Ok(Motion::Unproven);
        }
        ms.abs_delta[j] = speed;
        let whole_turn = space.wraps[j] && !h.iter().all(|x| (-PI..PI).contains(x));
        (ms.lo[j], ms.hi[j]) = if whole_turn { (-PI, PI) } else { (h[0].min(h[1]).min(h[2]), h[0].max(h[1]).max(h[2])) };
    }
    space.couplings.speeds(&mut ms.lo, &mut ms.hi, &mut ms.abs_delta);
    let span = ms.abs_delta.iter().fold(0.0f64, |m, &d| m.max(d));
    // Only a motion the robot can make is certified: both ends on their couplings, and every
    // limited joint within its limits all along (a joint's swept interval inside them; the
    // levers also bound each slide's displacement by its limits, `slide_reach`).
    let q = &mut ms.q;
    for (j, x) in q.iter_mut().enumerate() {
        *x = curve.hull(j).1[0];
    }
    let coupled_start = space.couplings.residual(q) <= FEASIBLE_TOL;
    for (j, x) in q.iter_mut().enumerate() {
        let x1 = curve.hull(j).1[1];
        *x = if space.wraps[j] { wrap(x1) } else { x1 };
    }
    let coupled = coupled_start && space.couplings.residual(q) <= FEASIBLE_TOL;
    let inside = (0..k)
        .all(|j| !model.limited[j] || (model.limits[j][0] - FEASIBLE_TOL <= ms.lo[j] && ms.hi[j] <= model.limits[j][1] + FEASIBLE_TOL));
    if !(coupled && inside) {
        return Ok(Motion::Unproven);
    }
    let npairs = model.pairs.len();
    let spans = levers.spans(model);
    let need = |p: usize| model.pairs[p].margin.max(clearance);
    // A pair one joint alone moves is proven for the whole motion when that joint's sweep stays
    // inside one of its spans (`planning/spans.rs`), proven at a need at least the motion's.
    // A pair two joints move, likewise, when both joints' sweeps stay inside its proven box, and
    // a pair of a longer chain proven by its swept ball when its first joint's sweep stays
    // inside the range it was recorded over (`prove_apart`; run here once per model, so that
    // verdicts do not depend on whether something else ran it first). Only the pairs with a
    // span or a box are asked (`MotionScratch::provable`): the others are never spanned.
    prove_apart(model);
    let apart = model.apart().unwrap_or(&[]);
    let provable = ms.provable.get_or_insert_with(|| provable_pairs(model, spans, apart));
    ms.spanned.clear();
    ms.spanned.resize(npairs, false);
    for &p in provable.iter() {
        let p = p as usize;
        ms.spanned[p] = spanned_over(model, spans, apart, p, need(p), &ms.lo, &ms.hi);
    }
    // (each pair's chain rate and growth are sums over its geoms' branches, summed once per geom;
    // a spanned pair's never read)
    ms.axes.motion(model, space, curve, &ms.lo, &ms.hi);
    levers.motion_sums(model, &ms.abs_delta, &mut ms.axes);
    for p in 0..npairs {
        if !ms.spanned[p] {
            ms.rates[p] = levers.side_sums(model, &ms.axes.chain, p);
        }
        ms.quads[p] = f64::NAN;
    }
    // (pose stamps are never 0 once placed: nothing cached from an earlier call is reused)
    ms.axes.forget();
    ms.scratch.forget_axes();
    let mut at = At { model, levers, axes: &mut ms.axes };
    let spanned = &ms.spanned;
    let stop = |e: Stop, t: f64| match e {
        Stop::Blocked => Ok(Motion::Blocked(t)),
        Stop::Undecided(u) => Err(u),
    };
    let (mut level, mut width): (Vec<(f64, usize, usize)>, f64) = if order == Order::MiddleFirst {
        // The middle first (a motion between proven poses, whose pairs mostly close from it both
        // ways at once); then each end for the pairs still open on its half.
        space.place(curve, 0.5, q);
        at.axes.at(curve, 0.5);
        ms.scratch.place(model, q, false);
        ms.states += 1;
        ms.open.clear();
        ms.next.clear();
        for (p, &spanned) in spanned.iter().enumerate() {
            if spanned {
                #[cfg(test)]
                at.axes.covers.push((p, 0.0, [0.0, f64::INFINITY]));
                continue;
            }
            match radius(&mut at, &mut ms.scratch, p, ms.rates[p], &mut ms.quads[p], need(p), [0.5, 0.5]) {
                Ok([back, fwd]) => {
                    // (a NaN radius leaves its half open)
                    if back.is_nan() || back < 0.5 {
                        ms.open.push(Open { pair: p as u32, r0: 0.0, r1: back });
                    }
                    if fwd.is_nan() || fwd < 0.5 {
                        ms.next.push(Open { pair: p as u32, r0: fwd, r1: 0.0 });
                    }
                }
                Err(e) => return stop(e, 0.5),
            }
        }
        if !ms.open.is_empty() {
            space.place(curve, 0.0, q);
            at.axes.at(curve, 0.0);
            ms.scratch.place_pairs(model, q, ms.open.iter().map(|o| o.pair as usize));
            ms.states += 1;
        }
        let mut kept = 0;
        for i in 0..ms.open.len() {
            let o = ms.open[i];
            let p = o.pair as usize;
            match radius(&mut at, &mut ms.scratch, p, ms.rates[p], &mut ms.quads[p], need(p), [f64::NEG_INFINITY, 0.5 - o.r1]) {
                Ok([_, r0]) if r0 + o.r1 >= 0.5 => {}
                Ok([_, r0]) => {
                    ms.open[kept] = Open { r0, ..o };
                    kept += 1;
                }
                Err(e) => return stop(e, 0.0),
            }
        }
        ms.open.truncate(kept);
        let left = kept;
        if !ms.next.is_empty() {
            space.place(curve, 1.0, q);
            at.axes.at(curve, 1.0);
            ms.scratch.place_pairs(model, q, ms.next.iter().map(|o| o.pair as usize));
            ms.states += 1;
        }
        for i in 0..ms.next.len() {
            let o = ms.next[i];
            let p = o.pair as usize;
            match radius(&mut at, &mut ms.scratch, p, ms.rates[p], &mut ms.quads[p], need(p), [0.5 - o.r0, f64::NEG_INFINITY]) {
                Ok([r1, _]) if o.r0 + r1 >= 0.5 => {}
                Ok([r1, _]) => ms.open.push(Open { r1, ..o }),
                Err(e) => return stop(e, 1.0),
            }
        }
        let mut level = Vec::new();
        if left > 0 {
            level.push((0.0, 0, left));
        }
        if ms.open.len() > left {
            level.push((0.5, left, ms.open.len()));
        }
        (level, 0.5)
    } else {
        // The end first (a planner's new state often collides), by spheres wherever they are
        // apart; then the start, exact where the spheres do not close the motion; then the end
        // again, exact, for the pairs still open that it measured by spheres only.
        space.place(curve, 1.0, q);
        at.axes.at(curve, 1.0);
        ms.scratch.place(model, q, false);
        ms.states += 1;
        for (p, &spanned) in spanned.iter().enumerate() {
            if spanned {
                ms.radius1[p] = f64::INFINITY;
                #[cfg(test)]
                at.axes.covers.push((p, 0.0, [0.0, f64::INFINITY]));
                continue;
            }
            match radius(&mut at, &mut ms.scratch, p, ms.rates[p], &mut ms.quads[p], need(p), [0.0, f64::NEG_INFINITY]) {
                Ok([r, _]) => ms.radius1[p] = r,
                Err(e) => return stop(e, 1.0),
            }
        }
        space.place(curve, 0.0, q);
        at.axes.at(curve, 0.0);
        ms.scratch.place(model, q, false);
        ms.states += 1;
        ms.open.clear();
        ms.next.clear();
        for p in 0..npairs {
            let r1 = ms.radius1[p];
            if r1 >= 1.0 {
                continue;
            }
            match radius(&mut at, &mut ms.scratch, p, ms.rates[p], &mut ms.quads[p], need(p), [f64::NEG_INFINITY, 1.0 - r1]) {
                Ok([_, r0]) if r0 + r1 >= 1.0 => {}
                Ok([_, r0]) => ms.next.push(Open { pair: p as u32, r0, r1 }),
                Err(e) => return stop(e, 0.0),
            }
        }
        if !ms.next.is_empty() {
            space.place(curve, 1.0, q);
            at.axes.at(curve, 1.0);
            // (only what the open pairs read: `Scratch::place_pairs`)
            ms.scratch.place_pairs(model, q, ms.next.iter().map(|o| o.pair as usize));
            ms.states += 1;
            for o in &ms.next {
                let p = o.pair as usize;
                match radius(&mut at, &mut ms.scratch, p, ms.rates[p], &mut ms.quads[p], need(p), [1.0 - o.r0, f64::NEG_INFINITY]) {
                    Ok([r1, _]) if o.r0 + r1 >= 1.0 => {}
                    Ok([r1, _]) => ms.open.push(Open { r1: r1.max(o.r1), ..*o }),
                    Err(e) => return stop(e, 1.0),
                }
            }
        }
        // Breadth first: intervals of one level, each with its open pairs (contiguous in `open`).
        (if ms.open.is_empty() { Vec::new() } else { vec![(0.0, 0, ms.open.len())] }, 1.0)
    };
    let mut verdict = Ok(Motion::Certified);
    'levels: while !level.is_empty() {
        if width * span < MIN_STEP {
            verdict = Ok(Motion::Unproven);
            break;
        }
        let half = width * 0.5;
        ms.next.clear();
        let mut next_level = Vec::with_capacity(level.len() * 2);
        ms.lanes.from = None;
        for (i, &(t0, start, end)) in level.iter().enumerate() {
            if ms.states >= MAX_STATES {
                verdict = Ok(Motion::Unproven);
                break 'levels;
            }
            let tm = t0 + half;
            // (four states' frames at once where the level holds two or more from here)
            if i % 4 == 0 && level.len() - i >= 2 {
                let ts = std::array::from_fn(|l| level[(i + l).min(level.len() - 1)].0 + half);
                ms.lanes.place(model, space, curve, ts, i);
            }
            let pairs = ms.open[start..end].iter().map(|o| o.pair as usize);
            at.axes.at(curve, tm);
            match ms.lanes.of(i) {
                Some(frames) => ms.scratch.place_pairs_from(model, frames, pairs),
                None => {
                    space.place(curve, tm, q);
                    ms.scratch.place_pairs(model, q, pairs);
                }
            }
            ms.states += 1;
            ms.mid.clear();
            for o in &ms.open[start..end] {
                let p = o.pair as usize;
                // What the midpoint must give back to close the first half, and on to close the
                // second.
                match radius(&mut at, &mut ms.scratch, p, ms.rates[p], &mut ms.quads[p], need(p), [half - o.r0, half - o.r1]) {
                    Ok(rm) => ms.mid.push((*o, rm)),
                    Err(e) => {
                        verdict = stop(e, tm);
                        break 'levels;
                    }
                }
            }
            let s = ms.next.len();
            // (a NaN radius leaves the half open)
            ms.next.extend(
                ms.mid
                    .iter()
                    .filter(|(o, [back, _])| (o.r0 + back).is_nan() || o.r0 + back < half)
                    .map(|&(o, [back, _])| Open { r1: back, ..o }),
            );
            if ms.next.len() > s {
                next_level.push((t0, s, ms.next.len()));
            }
            let s = ms.next.len();
            ms.next.extend(
                ms.mid
                    .iter()
                    .filter(|(o, [_, fwd])| (fwd + o.r1).is_nan() || fwd + o.r1 < half)
                    .map(|&(o, [_, fwd])| Open { r0: fwd, ..o }),
            );
            if ms.next.len() > s {
                next_level.push((tm, s, ms.next.len()));
            }
        }
        std::mem::swap(&mut ms.open, &mut ms.next);
        level = next_level;
        width = half;
    }
    verdict
}

/// Each motion's verdict and the states its proof placed, in motion order.
pub type Verdicts = Vec<(Motion, usize)>;

/// The verdict on each motion `starts[i] → goals[i]` (`(B, K)` row-major each; continuous
/// hinges along the short arc, other joints straight and unclamped) with every pair above
/// `max(margin, clearance)` metres, `clearance` in `(0, MAX_CLEARANCE]`, and the states each
/// placed; in motion order, in parallel on rayon's current pool. Every motion is decided
/// alone, so the result does not depend on the number of threads.
pub fn certify_motions(model: &RobotModel, starts: &[f64], goals: &[f64], clearance: f64) -> Result<Verdicts> {
    check_clearance(clearance)?;
    certify_each(model, same_shape(model, &[starts, goals])?, &|i| format!("motion {i}"), None, |space, ms, d, i, k| {
        let (a, g) = (&starts[i * k..(i + 1) * k], &goals[i * k..(i + 1) * k]);
        space.delta(a, g, &mut d[..k]);
        certify_curve(model, Levers::of(model), space, &Line { a, delta: &d[..k] }, clearance, Order::EndFirst, ms)
    })
}

/// The verdict on each quadratic Bézier `starts[i] → vias[i] → goals[i]` (`Bezier`: a parabolic
/// blend at the corner `vias[i]`; short arcs on continuous hinges), as `certify_motions`.
pub fn certify_blends(model: &RobotModel, starts: &[f64], vias: &[f64], goals: &[f64], clearance: f64) -> Result<Verdicts> {
    check_clearance(clearance)?;
    certify_each(model, same_shape(model, &[starts, vias, goals])?, &|i| format!("blend {i}"), None, |space, ms, d, i, k| {
        let (a, v, g) = (&starts[i * k..(i + 1) * k], &vias[i * k..(i + 1) * k], &goals[i * k..(i + 1) * k]);
        let (d1, d2) = d.split_at_mut(k);
        space.delta(a, v, d1);
        space.delta(v, g, d2);
        certify_curve(model, Levers::of(model), space, &Bezier { p0: a, d1, d2 }, clearance, Order::EndFirst, ms)
    })
}

/// As `certify_motions` (without `vias`) or `certify_blends`, each curve taken as given, in
/// unwrapped coordinates: `Δ = goal − start` (`via − start`, `goal − via`) on every joint,
/// continuous hinges included, however far (no short arc chosen): the motion a timed path
/// crosses (`planning/timing.rs`), even where a step is half a turn or its unwrapped values
/// round past one. (Where every step is a short arc, the same motions as those calls'.) Each
/// proof starts as `order` says.
pub fn certify_as_given(
    model: &RobotModel,
    starts: &[f64],
    vias: Option<&[f64]>,
    goals: &[f64],
    clearance: f64,
    order: Order,
) -> Result<Verdicts> {
    // (no motion is refused here, as `same_shape` refuses it; `certify_given` checks the rest)
    check_clearance(clearance)?;
    if starts.is_empty() {
        model.check_poses(starts)?;
    }
    Ok(match vias {
        None => certify_given(model, [starts, goals], [&[], &[], &[]], clearance, order)?.0,
        Some(vias) => certify_given(model, [&[], &[]], [starts, vias, goals], clearance, order)?.1,
    })
}

/// `certify_as_given` of straight motions `lines` (`[starts, goals]`) and of blends `blends`
/// (`[starts, vias, goals]`), `(B, K)` row-major each, in one parallel batch: a caller with
/// both kinds (a timed path's parts and its blends) pays one split of the work over the
/// threads, and one wait for the slowest motion, instead of two. The lines' verdicts, then the
/// blends'; each motion is decided alone, so the result is that of two calls. Either kind may
/// be empty (no motion of it). An error names a line "motion i" and a blend "blend j", each
/// by its index among its kind. Each proof starts as `order` says.
pub fn certify_given(
    model: &RobotModel,
    lines: [&[f64]; 2],
    blends: [&[f64]; 3],
    clearance: f64,
    order: Order,
) -> Result<(Verdicts, Verdicts)> {
    check_clearance(clearance)?;
    let count = |a: &[&[f64]]| if a.iter().all(|a| a.is_empty()) { Ok(0) } else { same_shape(model, a) };
    let (nl, nb) = (count(&lines)?, count(&blends)?);
    let name = |i: usize| if i < nl { format!("motion {i}") } else { format!("blend {}", i - nl) };
    let k = model.njoint();
    let length = |i: usize| {
        let (rows, j) = if i < nl { (&lines[..], i) } else { (&blends[..], i - nl) };
        rows.windows(2).map(|w| travel(&w[0][j * k..(j + 1) * k], &w[1][j * k..(j + 1) * k])).sum()
    };
    let mut all = certify_each(model, nl + nb, &name, Some(&length), |space, ms, d, i, k| {
        if i < nl {
            let (a, g) = (&lines[0][i * k..(i + 1) * k], &lines[1][i * k..(i + 1) * k]);
            diff(a, g, &mut d[..k]);
            return certify_curve(model, Levers::of(model), space, &Line { a, delta: &d[..k] }, clearance, order, ms);
        }
        let r = (i - nl) * k..(i - nl + 1) * k;
        let (a, v, g) = (&blends[0][r.clone()], &blends[1][r.clone()], &blends[2][r]);
        let (d1, d2) = d.split_at_mut(k);
        diff(a, v, d1);
        diff(v, g, d2);
        certify_curve(model, Levers::of(model), space, &Bezier { p0: a, d1, d2 }, clearance, order, ms)
    })?;
    let blend_verdicts = all.split_off(nl);
    Ok((all, blend_verdicts))
}

/// `out = b − a` on every joint: a step taken as given (`certify_as_given`), no short arc chosen.
fn diff(a: &[f64], b: &[f64], out: &mut [f64]) {
    out.iter_mut().zip(a.iter().zip(b)).for_each(|(o, (a, b))| *o = b - a);
}

/// The number of motions in `arrays`, `(B, K)` row-major each (B ≥ 1) and all of one shape.
fn same_shape(model: &RobotModel, arrays: &[&[f64]]) -> Result<usize> {
    let b = model.check_poses(arrays[0])?;
    for a in &arrays[1..] {
        if a.len() != arrays[0].len() {
            return Err(Error::InvalidInput(format!("the motions' arrays differ in shape: {} and {} values", arrays[0].len(), a.len())));
        }
        model.check_poses(a)?;
    }
    Ok(b)
}

/// `one(space, scratch, buffer of 2K, i, K)` for each motion `i < b`, in parallel on rayon's
/// current pool, one motion a work item, each worker's scratch reused across its items; an
/// error names the first motion that fails in order, as `name(i)` (its kind and its index
/// among its kind: "motion 3", "blend 0"). The caller checks the clearance and the arrays.
fn certify_each<F>(
    model: &RobotModel,
    b: usize,
    name: &(dyn Fn(usize) -> String + Sync),
    travel: Option<&Travel<'_>>,
    one: F,
) -> Result<Verdicts>
where
    F: Fn(&Space, &mut MotionScratch, &mut [f64], usize, usize) -> std::result::Result<Motion, Undecided> + Sync,
{
    each_task(model, b, name, travel, |space, ms, d, i, k| one(space, ms, d, i, k).map(|m| (m, ms.states)))
}

/// Batches of fewer motions run on the calling thread (`threads::map_shared`): a short timed
/// path's chord, parts and blends, tens of µs each, gain little from a sibling woken and steered
/// per batch, several batches a call (`benches/timing.py`'s median per planned path was
/// 0.35-0.58 ms with every batch of two or more shared, 0.27-0.46 ms in the table before it, in
/// a noisier hour).
const SHARED_FROM: usize = 4;

/// `one(space, scratch, buffer of 3K, i, K)` for each task `i < b` (one or more motions, each
/// decided alone on `scratch`), as `certify_each` runs its motions: in parallel, each worker
/// taking the next task as it frees up (`threads::map_shared`: a motion is 10 µs to
/// milliseconds of work, and a timed path's batches are a handful of unequal tasks; fewer than
/// [`SHARED_FROM`] on the calling thread), the longest first where `travel` gives each task's
/// length, an error named `name(i)`; the results in task order.
fn each_task<T, F>(
    model: &RobotModel,
    b: usize,
    name: &(dyn Fn(usize) -> String + Sync),
    travel: Option<&Travel<'_>>,
    one: F,
) -> Result<Vec<T>>
where
    T: Send,
    F: Fn(&Space, &mut MotionScratch, &mut [f64], usize, usize) -> std::result::Result<T, Undecided> + Sync,
{
    let k = model.njoint();
    let wraps = model.continuous();
    let space = Space { lo: vec![f64::NEG_INFINITY; k], hi: vec![f64::INFINITY; k], wraps, couplings: model.couplings.clone() };
    // The tasks taken longest first where `travel` says which (a task's proof grows with its
    // motion's length): the last one taken, which one worker runs while the other waits, is then
    // a short one. Each task is decided alone, so the order changes when it runs, not its answer.
    let mut order: Vec<usize> = (0..b).collect();
    if let Some(travel) = travel {
        let t: Vec<f64> = (0..b).map(travel).collect();
        order.sort_by(|&x, &y| t[y].total_cmp(&t[x]));
    }
    // (each worker takes the next task as it frees up: `threads::map_shared`)
    let taken: Vec<Result<T>> = crate::threads::map_shared(
        b,
        SHARED_FROM,
        || (Spare::take(model), vec![0.0; 3 * k]),
        |(ms, d), n| {
            let i = order[n];
            crate::cancel::check()?;
            one(&space, ms, d, i, k).map_err(|e| e.error(model, name(i)))
        },
    );
    let mut parts: Vec<Option<Result<T>>> = (0..b).map(|_| None).collect();
    for (&i, r) in order.iter().zip(taken) {
        parts[i] = Some(r);
    }
    first_error(parts.into_iter().map(|r| r.expect("every task ran")).collect())
}

/// A task's joint travel, `Σ_j |Δ_j|` over its motion (the sum of its curve's legs for a blend):
/// what `each_task` takes the longest tasks first by.
type Travel<'a> = dyn Fn(usize) -> f64 + Sync + 'a;

/// `Σ_j |b_j − a_j|`.
fn travel(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| (b - a).abs()).sum()
}

/// For each of `b` tasks, the first of its straight motions that is certified, taken as given
/// (`certify_as_given`: `Δ = goal − start` on every joint), with every pair above `max(margin,
/// clearance)` metres: `motion(i, n, start, goal)` writes task `i`'s `n`-th motion (`(K,)`
/// each) and says whether to certify it (`Some(false)`: skip it, `None`: the task has no more),
/// the motions tried in order until one is certified; `None` where none is. The tasks in
/// parallel, each motion decided alone (so the answer is that of certifying each task's motions
/// in turn, whatever the thread count), and none waits for another task's: a task whose first
/// motion is blocked goes on to its next at once. Each proof starts as `order` says. An error
/// names the task, `name(i)`.
pub(crate) fn first_certified(
    model: &RobotModel,
    b: usize,
    name: &(dyn Fn(usize) -> String + Sync),
    clearance: f64,
    order: Order,
    motion: impl Fn(usize, usize, &mut [f64], &mut [f64]) -> Option<bool> + Sync,
) -> Result<Vec<Option<usize>>> {
    check_clearance(clearance)?;
    // (a task's first motion's travel)
    let k = model.njoint();
    let length = |i: usize| {
        let (mut a, mut g) = (vec![0.0; k], vec![0.0; k]);
        motion(i, 0, &mut a, &mut g).map_or(0.0, |_| travel(&a, &g))
    };
    each_task(model, b, name, Some(&length), |space, ms, buf, i, k| {
        let (a, rest) = buf.split_at_mut(k);
        let (g, d) = rest.split_at_mut(k);
        let mut n = 0;
        while let Some(given) = motion(i, n, a, g) {
            if given {
                diff(a, g, d);
                if certify_curve(model, Levers::of(model), space, &Line { a, delta: d }, clearance, order, ms)? == Motion::Certified {
                    return Ok(Some(n));
                }
            }
            n += 1;
        }
        Ok(None)
    })
}

/// The model's spans (`planning/spans.rs`), per candidate pair.
pub(crate) fn joint_spans(model: &RobotModel) -> &[PairSpans] {
    Levers::of(model).spans(model)
}

/// Proves pairs clear over boxes of joint values, once per model (`RobotModel::apart`): from
/// then on the labeller and the fast paths skip a pair in every pose inside its box.
///
/// - A pair one joint alone moves: its widest span of `planning/spans.rs`.
/// - A pair two joints move (a Panda's link 5 against its link 7 and its hand): the box of both
///   joints' sampling ranges, by branch and bound ([`box_clear`]), when it can be proven whole
///   within [`BOX_CELLS`] cells. (Three joints were tried: 1-2 % fewer instructions per pose for
///   5 to 10 times the 0.02-0.05 s this takes on a bundled model.)
/// - A pair of a longer chain with one geom fixed in the world, where the ball its moving geom
///   sweeps about the chain's first hinge proves it clear in every configuration
///   (`swept_ball_clear`): recorded over that joint's range (a scene's obstacle beyond an
///   arm's reach from its shoulder; on MotionBenchMaker's scenes a quarter of such pairs).
///
/// Exact: a span, a box or a ball proves the pair more than `max(margin, MAX_CLEARANCE)` apart at every
/// pose inside it, so the pair is neither in contact nor within any clearance a certificate
/// asks (`broad::MAX_CLEARANCE`), and its tests would have said so. Labels, `collides` and
/// certificates are the same with the proofs as without (`tests`), only cheaper: on a Panda the
/// link 0 / link 1 pair reaches the narrow phase in every pose, and never touches. (One
/// difference: a pair parry cannot decide, `collide::Undecided`, is decided clear inside its
/// box once the proofs exist; the Python entry points, `plan_path` and `certify_motions` always
/// make them first.)
///
/// Sequential and a function of the model alone (a fresh scratch, pairs in order): 0.02-0.05 s on
/// each bundled model.
pub fn prove_apart(model: &RobotModel) {
    model.apart.get_or_init(|| {
        let levers = Levers::of(model);
        let ranges = model.sampling_ranges().ok();
        let mut s = Scratch::new(model);
        let mut gaps = Gaps::of(model);
        joint_spans(model)
            .iter()
            .enumerate()
            .map(|(p, (j, spans))| {
                if let Some(taken) = model.inherited.as_ref().and_then(|i| i.apart(p)) {
                    return taken;
                }
                if *j != u32::MAX {
                    return match spans.iter().max_by(|a, b| (a[1] - a[0]).total_cmp(&(b[1] - b[0]))) {
                        Some(&[lo, hi]) => Apart { joints: [*j, u32::MAX], lo: [lo, f64::NAN], hi: [hi, f64::NAN] },
                        None => Apart::NONE,
                    };
                }
                match (&ranges, levers.joints(p).as_slice()) {
                    (Some(r), &[a, b])
                        if swept_ball_clear(model, levers, &mut s, p, r, &mut gaps)
                            || box_clear(model, &mut s, p, [a, b], r, [levers.rows[p * levers.k + a], levers.rows[p * levers.k + b]]) =>
                    {
                        Apart { joints: [a as u32, b as u32], lo: [r[a][0], r[b][0]], hi: [r[a][1], r[b][1]] }
                    }
                    // (a longer chain: its ball proves it in every configuration, recorded over
                    // the range of its first joint, whose anchor it is)
                    (Some(r), &[a, _, _, ..]) if swept_ball_clear(model, levers, &mut s, p, r, &mut gaps) => {
                        Apart { joints: [a as u32, u32::MAX], lo: [r[a][0], f64::NAN], hi: [r[a][1], f64::NAN] }
                    }
                    _ => Apart::NONE,
                }
            })
            .collect()
    });
    // The pairs proven clear over the whole sampling box leave the four-pose broad phase's lists
    // for poses inside that box, where `Apart::holds` would skip them anyway.
    if let (Some(apart), Ok(ranges)) = (model.apart(), model.sampling_ranges()) {
        model.pruned4.get_or_init(|| {
            let (lo, hi): (Vec<f64>, Vec<f64>) = ranges.iter().map(|r| (r[0], r[1])).unzip();
            let lists = crate::model::broad::Lists4::without(&model.broad, |k| apart[k as usize].covers(&lo, &hi));
            crate::model::Pruned4 { lists, ranges }
        });
    }
}

/// Whether pair `p`, one of whose geoms is fixed in the world (`Levers::solo`: the chain is the
/// other geom's branch alone), is proven above its span need (`spans::span_need`) in every
/// configuration by the ball the moving geom sweeps about its chain's first joint `a`, a hinge:
/// every point of the geom stays within `R_a` of that joint's anchor (the pair's lever for `a`,
/// `joint_reach`: a bound for every configuration), and no joint moves the anchor (none is above
/// `a` on the branch, so `a` is also the first joint of its body), so the pair's distance is at least the fixed geom's distance from the
/// anchor (`Scratch::point_lower_bound`, exact support points) less `R_a`, with the rounding
/// slack (`slack_above`). One bound for the pair where `box_clear`'s branch and bound places
/// tens of cells: a scene's obstacles beside a Panda's second link, 40-70 each on
/// MotionBenchMaker's scenes. `ranges`: the model's sampling ranges, the pose placed (any pose
/// serves: the anchor and the fixed geom do not move). The fixed geom's distance from `a`'s
/// anchor is the same for every pair of it with a chain from `a` (a scene's obstacle and each
/// geom of an arm): `gaps` keeps it, per fixed geom and joint (`(ngeom · K)`, NaN until
/// measured; `Gaps`).
fn swept_ball_clear(model: &RobotModel, levers: Levers, s: &mut Scratch, p: usize, ranges: &[[f64; 2]], gaps: &mut Gaps) -> bool {
    let g = levers.solo[p];
    if g == u32::MAX || has_cloud(model, p) {
        return false;
    }
    // The chain's first joint `a`, where it qualifies (a solo pair's chain is its moving geom's
    // branch alone: the same for every pair of that geom).
    if gaps.first[g as usize] == Gaps::UNSEEN {
        // (MuJoCo numbers bodies parent first and joints in body order: the chain's first joint
        // is its least, checked to be above the others)
        gaps.first[g as usize] = match levers.chain(p).iter().map(|&e| entry_joint(e)).min() {
            Some(a) => {
                let above = |j: usize| {
                    let mut b = model.joints[j].body;
                    while b != model.joints[a].body && b != 0 {
                        b = model.body_parent[b];
                    }
                    b == model.joints[a].body
                };
                if model.joints[a].hinge && levers.chain(p).iter().all(|&e| above(entry_joint(e))) {
                    a as u32
                } else {
                    Gaps::NONE
                }
            }
            None => Gaps::NONE,
        };
    }
    let a = match gaps.first[g as usize] {
        Gaps::NONE => return false,
        a => a as usize,
    };
    let jnt = &model.joints[a];
    let pair = &model.pairs[p];
    let fixed = if pair.g1 == g as usize { pair.g2 } else { pair.g1 };
    let at = fixed * levers.k + a;
    if gaps.gap[at].is_nan() {
        let q: Vec<f64> = ranges.iter().map(|r| 0.5 * (r[0] + r[1])).collect();
        s.place_pairs(model, &q, std::iter::once(p));
        // (the anchor where `a` turns: its body's frame before its joints, `a` the first of them)
        let anchor = model.body_local[jnt.body] * nalgebra::Point3::from(jnt.anchor);
        gaps.gap[at] = s.point_lower_bound(model, fixed, model.body_parent[jnt.body], &anchor.coords);
    }
    slack_above(gaps.gap[at] - levers.rows[p * levers.k + a], span_need(model, p)) > 0.0
}

/// What `swept_ball_clear` finds once for every pair it serves, within one pass over a model's
/// pairs: the distance of a fixed geom from a joint's anchor (`gap`, per geom and joint, NaN
/// until measured: a bound is never NaN, `-inf` where none is proven), and a moving geom's
/// chain's first joint where its swept ball applies (`first`, per geom: `UNSEEN`, `NONE`, or
/// the joint).
pub(crate) struct Gaps {
    gap: Vec<f64>,
    first: Vec<u32>,
}

impl Gaps {
    const UNSEEN: u32 = u32::MAX - 1;
    const NONE: u32 = u32::MAX;

    /// Nothing measured yet, for `model`'s geoms and joints.
    pub(crate) fn of(model: &RobotModel) -> Gaps {
        Gaps { gap: vec![f64::NAN; model.geoms.len() * model.njoint()], first: vec![Gaps::UNSEEN; model.geoms.len()] }
    }
}

/// Most cells [`box_clear`] places for one pair before it gives up.
pub(crate) const BOX_CELLS: usize = 16_384;

/// Whether candidate pair `p`, whose distance depends on joints `joints` alone, is proven above
/// its span need (`spans::span_need`) at every pose with those joints in their ranges of `all`
/// (the model's sampling ranges), their levers
/// `levers` (`Levers`). Branch and bound: a cell with centre `c` and half-widths `h` is proven
/// when the pair's lower bound at `c` exceeds the need by `Σ_i h_i·R_i`, the most its distance
/// can fall within the cell (module docs, step 1); else it is halved across its longer side (in
/// `h_i·R_i`), or the whole box fails where a centre (or a point of a coarse grid, tried where
/// the first `GRID²` cells do not prove the box) is not above the need, past [`BOX_CELLS`]
/// cells, or where the narrow phase cannot bound the pair. The other joints stay at mid-range:
/// they move both geoms together. A function of the model alone (cells in a fixed order, the
/// pair's remembered axis forgotten first).
fn box_clear(model: &RobotModel, s: &mut Scratch, p: usize, joints: [usize; 2], all: &[[f64; 2]], levers: [f64; 2]) -> bool {
    box_clear_by(model, s, p, joints, all, levers, true)
}

/// `box_clear`, trying the bounding spheres first (`sphere_box_clear`) when `spheres`.
fn box_clear_by(
    model: &RobotModel,
    s: &mut Scratch,
    p: usize,
    joints: [usize; 2],
    all: &[[f64; 2]],
    levers: [f64; 2],
    spheres: bool,
) -> bool {
    let ranges = joints.map(|j| all[j]);
    if !levers.iter().all(|r| r.is_finite() && *r > 0.0)
        || !ranges.iter().all(|r| r[0].is_finite() && r[1].is_finite())
        || has_cloud(model, p)
    {
        return false;
    }
    let need = span_need(model, p);
    let mut q: Vec<f64> = all.iter().map(|r| 0.5 * (r[0] + r[1])).collect();
    if spheres && sphere_box_clear(model, s, p, joints, ranges, &mut q, need, levers) {
        return true;
    }
    s.forget_axes();
    // How far the pair is proven above its need with the two joints at `at`.
    let mut slack_at = |s: &mut Scratch, at: [f64; 2]| {
        (q[joints[0]], q[joints[1]]) = (at[0], at[1]);
        s.place_pairs(model, &q, std::iter::once(p));
        s.pair_lower_bound(model, p, f64::INFINITY, f64::INFINITY).map(|d| slack_above(d, need))
    };
    // A pair that comes within its need somewhere on a coarse grid cannot be proven: found
    // with GRID² cells, not after most of the budget. The cells come first, on that budget: a
    // scene's obstacles proven beside the first links take 7-39 cells each on MotionBenchMaker's
    // scenes, where the grid took 64 bounds before them.
    const GRID: usize = 8;
    if cells_clear(ranges, levers, GRID * GRID, |at| slack_at(s, at).ok()) {
        return true;
    }
    let grid = |i: usize, a: usize| ranges[i][0] + (a as f64 + 0.5) / GRID as f64 * (ranges[i][1] - ranges[i][0]);
    for a in 0..GRID {
        for b in 0..GRID {
            match slack_at(s, [grid(0, a), grid(1, b)]) {
                Ok(slack) if slack > 0.0 => {}
                _ => return false,
            }
        }
    }
    cells_clear(ranges, levers, BOX_CELLS, |at| slack_at(s, at).ok())
}

/// The branch and bound of `box_clear`: whether every cell of `ranges` is proven, a cell with
/// centre `c` and half-widths `h` when `slack(c)` (how far the pair is above its need there)
/// is at least `Σ_i h_i·levers_i`; else halved across its longer side (in `h_i·levers_i`), or
/// false where a centre's slack is not positive, is None, or past `budget` cells. Cells in a
/// fixed order (depth first, lower halves first).
fn cells_clear(ranges: [[f64; 2]; 2], levers: [f64; 2], budget: usize, mut slack: impl FnMut([f64; 2]) -> Option<f64>) -> bool {
    let mut cells = vec![ranges];
    let mut placed = 0usize;
    while let Some(cell) = cells.pop() {
        placed += 1;
        if placed > budget {
            return false;
        }
        let h = [0.5 * (cell[0][1] - cell[0][0]), 0.5 * (cell[1][1] - cell[1][0])];
        let Some(slack) = slack([cell[0][0] + h[0], cell[1][0] + h[1]]) else {
            return false;
        };
        // (the fall bound rounded up a little: it is a sum of products)
        let fall = (h[0] * levers[0] + h[1] * levers[1]) * (1.0 + 1e-12);
        if slack >= fall {
            continue;
        }
        if slack <= 0.0 {
            return false;
        }
        let i = if h[0] * levers[0] >= h[1] * levers[1] { 0 } else { 1 };
        let mid = cell[i][0] + h[i];
        let (mut lo, mut hi) = (cell, cell);
        lo[i][1] = mid;
        hi[i][0] = mid;
        cells.push(hi);
        cells.push(lo);
    }
    true
}

/// Most cells [`sphere_box_clear`] places for one pair before the exact proof takes over.
const SPHERE_CELLS: usize = 256;

/// `box_clear`'s branch and bound on the pair's bounding spheres alone (`broad::sphere_gap`, a
/// lower bound of its distance), without the narrow phase: true when every cell is proven, at
/// most [`SPHERE_CELLS`] cells; false (the exact proof decides) as soon as a cell's centre has
/// its spheres within the need, or past the budget. A scene's obstacles far from the first
/// links are proven so, where the exact proof's coarse grid alone costs 64 GJK runs a pair.
/// Sound as the exact proof is: each proven cell's centre gap exceeds the need by the most the
/// distance can fall within the cell, and the spheres hold the geoms.
#[allow(clippy::too_many_arguments)]
fn sphere_box_clear(
    model: &RobotModel,
    s: &mut Scratch,
    p: usize,
    joints: [usize; 2],
    ranges: [[f64; 2]; 2],
    q: &mut [f64],
    need: f64,
    levers: [f64; 2],
) -> bool {
    cells_clear(ranges, levers, SPHERE_CELLS, |at| {
        (q[joints[0]], q[joints[1]]) = (at[0], at[1]);
        s.place_pairs(model, q, std::iter::once(p));
        // (a pair the broad phase keeps no sphere for has an infinite gap: nothing to prove by)
        Some(model.broad.sphere_gap(&s.broad, p, &model.geoms).0 - need).filter(|x| x.is_finite())
    })
}

/// Pair `p`'s lever for joint `j` (0 for a joint at or above its common ancestor).
#[cfg(test)]
pub(crate) fn lever_of(model: &RobotModel, p: usize, j: usize) -> f64 {
    Levers::of(model).rows[p * model.njoint() + j]
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::model::desc::{ModelDesc, JOINT_HINGE, JOINT_SLIDE};
    use rand::{Rng, SeedableRng};

    /// A three-link arm over a floor beside a box: hinges about skew axes with off-origin
    /// anchors, and a body with a hinge then a slide (so its hinge is not `tight`). (Also
    /// `ik/mod.rs`'s test arm.)
    pub(crate) fn arm() -> RobotModel {
        RobotModel::new(arm_desc()).unwrap()
    }

    /// `arm` among eight more boxes in the world around it, some within its reach: the world's
    /// geoms then make several clusters (`model/broad.rs`).
    pub(crate) fn cluttered_arm() -> RobotModel {
        let mut d = arm_desc();
        for i in 0..8 {
            let a = i as f64 * 0.8;
            d.geom_id.push(d.geom_id.len() as i32);
            d.geom_type.push(6);
            d.geom_body.push(0);
            d.geom_pos.push([
                (0.35 + 0.05 * (i % 3) as f64) * a.cos(),
                (0.35 + 0.05 * (i % 3) as f64) * a.sin(),
                0.2 + 0.05 * (i % 4) as f64,
            ]);
            let q = nalgebra::Vector4::new(0.9, 0.1 * (i % 2) as f64, 0.2, 0.0).normalize();
            d.geom_quat.push([q[0], q[1], q[2], q[3]]);
            d.geom_size.push([0.04, 0.03 + 0.01 * (i % 3) as f64, 0.05]);
            d.geom_contype.push(1);
            d.geom_conaffinity.push(1);
            d.geom_margin.push(if i == 5 { 0.01 } else { 0.0 });
            d.geom_mesh.push(-1);
        }
        RobotModel::new(d).unwrap()
    }

    pub(crate) fn arm_desc() -> ModelDesc {
        let mut d = ModelDesc::example_pendulum();
        d.body_parent = vec![0, 0, 1, 2];
        d.body_weld = vec![0, 1, 2, 3];
        d.body_pos = vec![[0.0; 3], [0.0, 0.0, 0.3], [0.2, 0.0, 0.1], [0.3, 0.05, 0.0]];
        d.body_quat = vec![[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.9, 0.1, 0.3, 0.0], [1.0, 0.0, 0.0, 0.0]];
        d.jnt_type = vec![JOINT_HINGE, JOINT_HINGE, JOINT_SLIDE, JOINT_HINGE];
        d.jnt_body = vec![1, 2, 2, 3];
        d.jnt_pos = vec![[0.0; 3], [0.05, 0.0, 0.0], [0.0; 3], [0.0, 0.02, 0.01]];
        d.jnt_axis = vec![[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]];
        d.jnt_qpos0 = vec![0.0; 4];
        d.jnt_range = vec![[-3.0, 3.0], [-2.0, 2.0], [-0.1, 0.1], [-2.5, 2.5]];
        d.jnt_limited = vec![true; 4];
        d.geom_id = vec![0, 1, 2, 3, 4];
        d.geom_type = vec![0, 6, 3, 6, 6];
        d.geom_body = vec![0, 0, 1, 2, 3];
        d.geom_pos = vec![[0.0; 3], [0.45, 0.0, 0.25], [0.0, 0.0, 0.05], [0.1, 0.0, 0.0], [0.1, 0.0, 0.02]];
        d.geom_quat = vec![[1.0, 0.0, 0.0, 0.0]; 5];
        d.geom_size = vec![[1.0, 1.0, 0.1], [0.05, 0.08, 0.05], [0.04, 0.1, 0.0], [0.12, 0.03, 0.02], [0.1, 0.02, 0.03]];
        d.geom_contype = vec![1; 5];
        d.geom_conaffinity = vec![1; 5];
        d.geom_margin = vec![0.0, 0.0, 0.0, 0.01, 0.0];
        d.geom_mesh = vec![-1; 5];
        d
    }

    /// The pair's distance, clipped at 0 (GJK's separation; ~1e-8 relative).
    /// Prepares `axes` for `curve` as `certify_curve` does (its joints' speeds and swept
    /// intervals, `Axes::motion`, `Levers::motion_sums`) and returns the speeds.
    fn prepare<C: Curve>(model: &RobotModel, space: &Space, levers: Levers, axes: &mut Axes, curve: &C) -> Vec<f64> {
        let k = model.njoint();
        let (mut abs, mut lo, mut hi) = (vec![0.0; k], vec![0.0; k], vec![0.0; k]);
        for j in 0..k {
            let (speed, h) = curve.hull(j);
            abs[j] = speed;
            (lo[j], hi[j]) = (h[0].min(h[1]).min(h[2]), h[0].max(h[1]).max(h[2]));
        }
        axes.motion(model, space, curve, &lo, &hi);
        levers.motion_sums(model, &abs, axes);
        abs
    }

    /// The state-local rate `a` and its growth `b` of pair `p` (`Rate`), side by side over its
    /// chain, each term from its definition (the reference the per-geom suffix sums must match):
    /// per side, `|v| + r·|ω|` with the known joints' velocities `axes.vel`, the others at their
    /// levers; and `b`'s terms with each `U_m` and `C_m` summed anew.
    fn rates_by_pair(model: &RobotModel, levers: Levers, abs_delta: &[f64], s: &Scratch, axes: &Axes, p: usize) -> (f64, f64) {
        let pair = &model.pairs[p];
        let (mut a, mut b) = (0.0, 0.0);
        for side in 0..2u32 {
            let g = if side == 0 { pair.g1 } else { pair.g2 };
            let r = model.geoms[g].shape.radius;
            let entries: Vec<usize> = levers.chain(p).iter().filter(|&&e| e & SIDE == side).map(|&e| entry_joint(e)).collect();
            if entries.is_empty() {
                continue;
            }
            let c = model.broad.sphere_centre(&s.broad, g);
            let (mut omega, mut v, mut other, mut levered) = (nalgebra::Vector3::zeros(), nalgebra::Vector3::zeros(), 0.0, 0.0);
            let far = c.x.abs() + c.y.abs() + c.z.abs();
            for &j in &entries {
                let d = abs_delta[j];
                if d == 0.0 {
                    continue;
                }
                let lever = levers.reach[g * levers.k + j];
                levered += d * lever;
                if axes.known[j] {
                    let jnt = &model.joints[j];
                    let x = s.body(jnt.body);
                    let (anchor, axis) = ((x * nalgebra::Point3::from(jnt.anchor)).coords, x.rotation * jnt.axis.into_inner());
                    omega += axis * axes.vel[j];
                    v += axis.cross(&(c - anchor)) * axes.vel[j];
                    levered += axes.vel[j].abs() * (1.0 + anchor.x.abs() + anchor.y.abs() + anchor.z.abs() + far);
                } else {
                    other += d * lever;
                }
            }
            a += (v.norm() + r * omega.norm()) * (1.0 + 1e-9) + other + 1e-9 * levered;
            // (entries top down: those above `m` come before it)
            for (at, &m) in entries.iter().enumerate() {
                if !axes.known[m] || abs_delta[m] == 0.0 {
                    continue;
                }
                let rho = |i: usize| levers.centre[g * levers.k + i];
                let u: f64 = entries[..at].iter().filter(|&&i| model.joints[i].hinge).map(|&i| abs_delta[i]).sum();
                let c_m: f64 = entries[at..].iter().map(|&i| abs_delta[i] * rho(i)).sum();
                b += axes.acc[m] * (rho(m) + r) + abs_delta[m] * (u * (rho(m) + r) + c_m);
            }
        }
        (a, b)
    }

    /// Each pair's side of its chain is the tail of its geom's branch from the world, and the
    /// chain rate, the state-local rate and its growth summed once per geom over branches
    /// (`Levers::motion_sums`, `local_rate`) are the pair-by-pair sums over its chain, to
    /// rounding, on five bundled scenes (self pairs and scene pairs), with random straight
    /// motions and blends, some joints still, over several placed states (the sums of one state
    /// not read in another).
    #[test]
    fn rates_summed_per_geom_are_the_pairs_own() {
        for scene in ["panda_blocks", "xarm7_table", "shadow_hand", "vx300s_clutter", "ur5e_wall_box"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
            let levers = Levers::of(&model);
            let k = model.njoint();
            for (p, pair) in model.pairs.iter().enumerate() {
                let [n1, n2] = levers.sides[p];
                let chain = levers.chain(p);
                for (side, g, n) in [(0, pair.g1, n1), (1, pair.g2, n2)] {
                    let ours: Vec<u32> = chain.iter().filter(|&&e| e & SIDE == side).map(|e| e & !SIDE).collect();
                    let branch = levers.branch(g);
                    assert_eq!(ours.len(), n as usize, "{scene}: pair {p}");
                    assert_eq!(ours[..], branch[branch.len() - n as usize..], "{scene}: pair {p} side {side}");
                    for &e in &ours {
                        assert_eq!(levers.reach[g * k + entry_joint(e)], levers.rows[p * k + entry_joint(e)], "{scene}: pair {p}");
                    }
                }
            }
            let space = Space::of(&model).unwrap();
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
            let mut s = Scratch::new(&model);
            let mut axes = Axes::new(&model);
            let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * y.abs() || (x == y);
            let mut known = 0;
            for m in 0..20 {
                let step = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f64> {
                    (0..k).map(|_| if rng.random_bool(0.2) { 0.0 } else { rng.random_range(-0.5..0.5) }).collect()
                };
                let (a, d1, d2) = ((0..k).map(|j| 0.5 * (space.lo[j] + space.hi[j])).collect::<Vec<f64>>(), step(&mut rng), step(&mut rng));
                let (line, bezier) = (Line { a: &a, delta: &d1 }, Bezier { p0: &a, d1: &d1, d2: &d2 });
                let blend = m % 2 == 1;
                let abs = if blend {
                    prepare(&model, &space, levers, &mut axes, &bezier)
                } else {
                    prepare(&model, &space, levers, &mut axes, &line)
                };
                known += axes.known.iter().zip(&abs).filter(|(&k, &d)| k && d != 0.0).count();
                axes.forget();
                for _ in 0..3 {
                    let t = rng.random_range(0.0..1.0);
                    if blend {
                        axes.at(&bezier, t);
                    } else {
                        axes.at(&line, t);
                    }
                    let q: Vec<f64> = (0..k).map(|j| rng.random_range(space.lo[j]..space.hi[j])).collect();
                    s.place(&model, &q, false);
                    for p in 0..model.pairs.len() {
                        let (rate, quad) = (levers.side_sums(&model, &axes.chain, p), levers.side_sums(&model, &axes.quad, p));
                        assert!(close(rate, levers.rate(p, &abs)), "{scene}: pair {p}: {rate} {}", levers.rate(p, &abs));
                        let a = local_rate(&model, levers, &s, &mut axes, p);
                        let (want_a, want_b) = rates_by_pair(&model, levers, &abs, &s, &axes, p);
                        assert!((a - want_a).abs() <= 1e-9 * want_a, "{scene}: pair {p}: {a} {want_a}");
                        assert!(close(quad, want_b) || (quad - want_b).abs() <= 1e-12 * rate * rate, "{scene}: pair {p}: {quad} {want_b}");
                    }
                }
            }
            assert!(known > 20, "{scene}: {known}");
        }
    }

    /// `certify_curve` asks only `provable_pairs` whether a motion's sweep lies in a span or a
    /// proven box: on five bundled scenes, over sweeps of every width (a point, ±0.05 and ±0.5
    /// rad, a joint's whole range) at random places, every pair `spanned_over` holds for is
    /// among them; and it finds pairs spanned and pairs open in every scene.
    #[test]
    fn only_provable_pairs_are_ever_spanned() {
        for scene in ["panda_blocks", "xarm7_table", "shadow_hand", "vx300s_clutter", "ur5e_wall_box"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
            prove_apart(&model);
            let spans = Levers::of(&model).spans(&model);
            let apart = model.apart().unwrap();
            let provable = provable_pairs(&model, spans, apart);
            let ranges = model.sampling_ranges().unwrap();
            let k = model.njoint();
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
            let (mut spanned, mut open) = (0, 0);
            for m in 0..200 {
                let width = [0.0, 0.05, 0.5, f64::INFINITY][m % 4];
                let (mut lo, mut hi) = (vec![0.0; k], vec![0.0; k]);
                for (j, &[a, b]) in ranges.iter().enumerate() {
                    let c = rng.random_range(a..=b);
                    (lo[j], hi[j]) = ((c - width).max(a), (c + width).min(b));
                }
                for p in 0..model.pairs.len() {
                    if spanned_over(&model, spans, apart, p, model.pairs[p].margin.max(1e-6), &lo, &hi) {
                        assert!(provable.contains(&(p as u32)), "{scene}: pair {p} spanned, not provable");
                        spanned += 1;
                    } else {
                        open += 1;
                    }
                }
            }
            assert!(spanned > 0 && open > 0, "{scene}: {spanned} spanned, {open} open");
        }
    }

    /// A `solo` pair's chain is its geom's whole branch from the world, its rows that geom's
    /// reaches, and the other geom never moves: every pair of a solo geom has the same chain
    /// (joints and tightness) and rows, so their rates are one; the scene pairs of a fixed robot
    /// among still obstacles are solo, and no self pair is.
    #[test]
    fn solo_pairs_share_their_geoms_chain_and_rows() {
        for scene in ["panda_blocks", "xarm7_table", "shadow_hand", "vx300s_clutter", "ur5e_wall_box"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
            let levers = Levers::of(&model);
            let k = model.njoint();
            let mut first: std::collections::HashMap<u32, usize> = Default::default();
            let mut solo = 0;
            for (p, pair) in model.pairs.iter().enumerate() {
                let g = levers.solo[p];
                let moving = |g: usize| {
                    (0..model.body_parent.len()).any(|b| {
                        let mut c = model.geoms[g].body;
                        while c != 0 && c != b {
                            c = model.body_parent[c];
                        }
                        c == b && model.body_joints[b].1 > model.body_joints[b].0
                    })
                };
                if pair.kind == crate::model::pairs::PairKind::SelfCollision {
                    assert_eq!(g, u32::MAX, "{scene}: self pair {p}");
                }
                if g == u32::MAX {
                    continue;
                }
                solo += 1;
                let other = if g as usize == pair.g1 { pair.g2 } else { pair.g1 };
                assert!(!moving(other), "{scene}: pair {p}'s other geom moves");
                let q = *first.entry(g).or_insert(p);
                let joints = |p: usize| levers.chain(p).iter().map(|e| e & !SIDE).collect::<Vec<_>>();
                assert_eq!(joints(p), joints(q), "{scene}: pairs {p} and {q}");
                assert_eq!(levers.rows[p * k..(p + 1) * k], levers.rows[q * k..(q + 1) * k], "{scene}: pairs {p} and {q}");
            }
            // (a fixed robot among still obstacles: every scene pair is solo; the Shadow Hand has none)
            let scene_pairs = model.pairs.iter().filter(|p| p.kind == crate::model::pairs::PairKind::Scene).count();
            assert_eq!(solo, scene_pairs, "{scene}");
        }
    }

    /// Every proof of `prove_apart` holds where it says: at random poses inside each pair's span
    /// or box, every other joint anywhere in its range, the pair is clear of `MAX_CLEARANCE`
    /// by the exact narrow phase (`clear_of`); on arms with boxes over two hinges, the Panda's
    /// fingers (two slides), and the Shadow Hand's fingers.
    #[test]
    fn proofs_of_prove_apart_hold_inside_their_boxes() {
        use crate::model::broad::MAX_CLEARANCE;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let mut longer = 0;
        for scene in ["panda_blocks", "xarm7_table", "shadow_hand", "vx300s_clutter", "panda_shelf", "ur5e_wall_box"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
            prove_apart(&model);
            let ranges = model.sampling_ranges().unwrap();
            let levers = Levers::of(&model);
            let mut s = Scratch::new(&model);
            let (mut ones, mut twos) = (0, 0);
            for (k, a) in model.apart().unwrap().iter().enumerate() {
                if a.lo[0] > a.hi[0] || a.lo[0].is_nan() {
                    continue;
                }
                let two = a.joints[1] != u32::MAX;
                // (one entry: a one-joint pair's widest span, or a longer chain's swept ball over
                // its first joint's range, which holds in every configuration)
                longer += (levers.joints(k).len() > 2) as usize;
                (ones, twos) = if two { (ones, twos + 1) } else { (ones + 1, twos) };
                for _ in 0..200 {
                    let mut q: Vec<f64> = ranges.iter().map(|r| rng.random_range(r[0]..=r[1])).collect();
                    for i in 0..if two { 2 } else { 1 } {
                        q[a.joints[i] as usize] = rng.random_range(a.lo[i]..=a.hi[i]);
                    }
                    assert!(a.holds(&q));
                    s.place(&model, &q, false);
                    assert!(s.clear_of(&model, k, MAX_CLEARANCE).unwrap(), "{scene}: pair {k} not clear at {q:?}");
                }
            }
            // (the Shadow Hand's one-joint pairs are its phalanges, parent and child: never
            // candidates)
            assert!(twos > 0 && (ones > 0 || scene == "shadow_hand"), "{scene}: {ones} spans and {twos} boxes");
        }
        assert!(longer > 0, "no pair of a chain of three joints or more proven by its swept ball");
    }

    /// The bounding spheres' proof of a pair's box (`sphere_box_clear`) proves only boxes the
    /// exact one proves too, and it does prove some (obstacles far from the first links), so
    /// the boxes are those of the exact proof alone.
    #[test]
    fn boxes_proven_by_spheres_are_proven_exactly() {
        let (mut by_spheres, mut exact_only) = (0, 0);
        for scene in ["panda_blocks", "panda_shelf", "xarm7_table", "ur5e_wall_box", "vx300s_clutter"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
            let levers = Levers::of(&model);
            let ranges = model.sampling_ranges().unwrap();
            let mut s = Scratch::new(&model);
            for p in 0..model.pairs.len() {
                let &[a, b] = levers.joints(p).as_slice() else { continue };
                let lv = [levers.rows[p * levers.k + a], levers.rows[p * levers.k + b]];
                let need = span_need(&model, p);
                let mut q: Vec<f64> = ranges.iter().map(|r| 0.5 * (r[0] + r[1])).collect();
                let spheres = lv.iter().all(|r| r.is_finite() && *r > 0.0)
                    && sphere_box_clear(&model, &mut s, p, [a, b], [ranges[a], ranges[b]], &mut q, need, lv);
                let exact = box_clear_by(&model, &mut s, p, [a, b], &ranges, lv, false);
                assert!(!spheres || exact, "{scene}: pair {p}");
                by_spheres += spheres as usize;
                exact_only += (exact && !spheres) as usize;
                assert_eq!(box_clear(&model, &mut s, p, [a, b], &ranges, lv), exact, "{scene}: pair {p}");
            }
        }
        assert!(by_spheres > 0, "{by_spheres} by spheres, {exact_only} exactly only");
    }

    /// A pair proven by the ball its moving geom sweeps (`swept_ball_clear`) is clear in every
    /// configuration, not only inside its box: at random poses anywhere in the sampling box the
    /// exact narrow phase finds it clear of its need, over chains of two joints and longer (the
    /// same argument); and the ball proves scene pairs beside the second links of the Panda, the
    /// xArm and the UR5e, where the boxes' branch and bound needs tens of cells a pair.
    #[test]
    fn swept_balls_prove_only_pairs_clear_everywhere() {
        use rand::Rng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
        let (mut ones, mut twos, mut longer) = (0, 0, 0);
        for scene in ["panda_blocks", "panda_shelf", "xarm7_table", "ur5e_wall_box", "vx300s_clutter", "shadow_hand"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
            let levers = Levers::of(&model);
            let ranges = model.sampling_ranges().unwrap();
            let mut s = Scratch::new(&model);
            for p in 0..model.pairs.len() {
                if !swept_ball_clear(&model, levers, &mut s, p, &ranges, &mut Gaps::of(&model)) {
                    continue;
                }
                match levers.joints(p).len() {
                    1 => ones += 1,
                    2 => twos += 1,
                    _ => longer += 1,
                }
                for _ in 0..100 {
                    let q: Vec<f64> = ranges.iter().map(|r| rng.random_range(r[0]..=r[1])).collect();
                    s.place(&model, &q, false);
                    assert!(s.clear_of(&model, p, span_need(&model, p)).unwrap(), "{scene}: pair {p} not clear at {q:?}");
                }
            }
        }
        assert!(
            ones > 0 && twos >= 3 && longer > 0,
            "proven by their balls: {ones} pairs over one joint, {twos} over two, {longer} over more"
        );
    }

    /// The swept ball's anchor and reach where the bundled robots have neither: two hinges on one
    /// body, their anchors off the body's origin. A small ball sits on the second joint's anchor,
    /// so it sweeps a circle about the first joint's axis and the swept ball is tight in the
    /// circle's plane; obstacles (balls) in that plane just inside and just outside its reach.
    /// Each one proven is clear of its need at every first-joint angle of a fine grid (the
    /// second at random), and the ball proves some and not others. The pair is placed where the
    /// second joint turns the body (the middle of its range), so a pivot read off the placed
    /// body instead of the frame before its joints (0.09 m off) fails here.
    #[test]
    fn swept_balls_turn_about_the_first_anchor_of_a_two_hinge_body() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(31);
        let (mut proven, mut not) = (0, 0);
        let (pivot, rho, r) = (nalgebra::Vector3::new(0.15, -0.05, 0.55), (0.15f64 * 0.15 + 0.15 * 0.15).sqrt(), 0.02);
        for _ in 0..200 {
            let mut desc = ModelDesc::example_pendulum();
            desc.jnt_type = vec![JOINT_HINGE; 2];
            desc.jnt_body = vec![1, 1];
            desc.jnt_pos = vec![[0.15, -0.05, 0.0], [0.0, 0.1, 0.0]];
            desc.jnt_axis = vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]];
            desc.jnt_qpos0 = vec![0.0; 2];
            desc.jnt_range = vec![[-3.1, 3.1], [-1.0, 2.2]];
            desc.jnt_limited = vec![true; 2];
            let (phi, out) = (rng.random_range(-3.0..3.0f64), rng.random_range(-0.02..0.02));
            let at = pivot + (rho + r + 0.05 + out) * nalgebra::Vector3::new(phi.cos(), phi.sin(), 0.0);
            desc.geom_type = vec![2, 2];
            desc.geom_pos = vec![at.into(), [0.0, 0.1, 0.0]];
            desc.geom_size = vec![[0.05, 0.0, 0.0], [r, 0.0, 0.0]];
            let model = RobotModel::new(desc).unwrap();
            assert_eq!(model.pairs.len(), 1);
            let levers = Levers::of(&model);
            let ranges = model.sampling_ranges().unwrap();
            let mut s = Scratch::new(&model);
            if !swept_ball_clear(&model, levers, &mut s, 0, &ranges, &mut Gaps::of(&model)) {
                not += 1;
                continue;
            }
            proven += 1;
            for i in 0..=2000 {
                let q = [-3.1 + 6.2 * i as f64 / 2000.0, rng.random_range(-1.0..=2.2)];
                s.place(&model, &q, false);
                assert!(s.clear_of(&model, 0, span_need(&model, 0)).unwrap(), "ball at {at:?} not clear at {q:?}");
            }
        }
        assert!(proven >= 20 && not >= 20, "{proven} places proven, {not} not");
    }

    /// Skipping the pairs `prove_apart` proves clear changes no answer: labels (flags, pair
    /// counts, colliding pairs), `collides` and certificates are those of the same model without
    /// the proofs, on poses within the limits and on poses up to 1 rad beyond them (outside the
    /// spans and boxes, where nothing is skipped); and the proofs do skip pairs, over one joint
    /// and over two (the Panda's link 0 / link 1 pair, which reaches the narrow phase in every
    /// A model rebuilt after an edit of its world (`RobotModel::rebuilt`: one obstacle removed,
    /// another moved) takes over the proofs of the pairs it shares, and they are exactly those it
    /// would make itself: the same spans and boxes, bit for bit, as a model built from nothing.
    #[test]
    fn rebuilt_models_inherit_exactly_the_proofs_they_would_make() {
        for scene in ["panda_blocks", "ur5e_wall_box", "vx300s_clutter"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let desc: ModelDesc = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            let model = RobotModel::new(desc.clone()).unwrap();
            prove_apart(&model);
            let world: Vec<usize> = (0..desc.geom_body.len()).filter(|&g| desc.geom_body[g] == 0).collect();
            assert!(world.len() >= 2, "{scene}: {world:?}");
            let mut edited = desc.clone();
            edited.geom_pos[world[1]][2] += 0.05; // moved: its pairs are proved again
            let g = world[0]; // removed
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
            let rebuilt = model.rebuilt(&desc, edited.clone()).unwrap();
            let fresh = RobotModel::new(edited).unwrap();
            let taken = rebuilt.inherited.as_ref().unwrap().apart.as_ref().unwrap();
            let n_taken = taken.iter().filter(|a| a.is_some()).count();
            assert!(n_taken > 0 && n_taken < taken.len(), "{scene}: {n_taken} of {}", taken.len());
            prove_apart(&rebuilt);
            prove_apart(&fresh);
            assert_eq!(joint_spans(&rebuilt), joint_spans(&fresh), "{scene}");
            let bits = |m: &RobotModel| -> Vec<(u32, u32, u64, u64, u64, u64)> {
                m.apart()
                    .unwrap()
                    .iter()
                    .map(|a| (a.joints[0], a.joints[1], a.lo[0].to_bits(), a.lo[1].to_bits(), a.hi[0].to_bits(), a.hi[1].to_bits()))
                    .collect()
            };
            assert_eq!(bits(&rebuilt), bits(&fresh), "{scene}");
        }
    }

    /// pose, over its hinge's whole range).
    #[test]
    fn pairs_proven_apart_are_skipped_without_changing_any_answer() {
        use crate::collision::collide::{label_batch, LabelOptions};
        use crate::collision::fastpath::{certified_batch, collides_batch};
        for scene in ["panda_blocks", "xarm7_table", "ur5e_wall_box", "panda_shelf", "shadow_hand", "vx300s_clutter"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let desc: ModelDesc = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            let (plain, proven) = (RobotModel::new(desc.clone()).unwrap(), RobotModel::new(desc).unwrap());
            prove_apart(&proven);
            let apart = proven.apart().unwrap();
            assert!(plain.apart().is_none());
            let skipped = apart.iter().filter(|a| a.some()).count();
            assert!(skipped > 0, "{scene}: no pair proven apart");
            // (and boxes of two joints among them, where one joint's spans are not enough)
            assert!(apart.iter().any(|a| a.joints[1] != u32::MAX), "{scene}: no pair proven over two joints");
            let ranges = plain.sampling_ranges().unwrap();
            let wide: Vec<[f64; 2]> = ranges.iter().map(|r| [r[0] - 1.0, r[1] + 1.0]).collect();
            for (what, ranges) in [("within limits", &ranges), ("beyond them", &wide)] {
                let poses = crate::joints::sample::sample_uniform(ranges, 3000, 9).unwrap();
                let opts = LabelOptions { pairs: true, distance: false };
                let (a, b) = (label_batch(&plain, &poses, opts).unwrap(), label_batch(&proven, &poses, opts).unwrap());
                assert_eq!(a.colliding_pairs, b.colliding_pairs, "{scene}, {what}");
                for (x, y) in a.labels.iter().zip(&b.labels) {
                    assert_eq!(
                        (x.self_collides, x.scene_collides, x.n_pairs),
                        (y.self_collides, y.scene_collides, y.n_pairs),
                        "{scene}, {what}"
                    );
                }
                assert_eq!(collides_batch(&plain, &poses).unwrap(), collides_batch(&proven, &poses).unwrap(), "{scene}, {what}");
                assert_eq!(
                    certified_batch(&plain, &poses, 1e-6).unwrap(),
                    certified_batch(&proven, &poses, 1e-6).unwrap(),
                    "{scene}, {what}"
                );
            }
        }
        // the Panda's link 0 / link 1 pair (bodies 1 and 2, one hinge between them): proven over
        // the hinge's whole range
        let path = format!("{}/benches/data/panda_blocks.json", env!("CARGO_MANIFEST_DIR"));
        let model = RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap();
        prove_apart(&model);
        let k = (0..model.pairs.len())
            .find(|&k| {
                let p = &model.pairs[k];
                (model.geoms[p.g1].body, model.geoms[p.g2].body) == (1, 2)
            })
            .unwrap();
        let a = model.apart().unwrap()[k];
        let r = model.sampling_ranges().unwrap()[a.joints[0] as usize];
        let r = [r, [f64::NAN; 2]];
        assert_eq!((a.joints[0], a.lo[0], a.hi[0], a.joints[1]), (0, r[0][0], r[0][1], u32::MAX));
    }

    /// The rate bounds hold: between a state and one `τ` along the motion, no pair's distance
    /// changes by more than each form of `Rate::drop(τ)` alone (the chain rate, the state-local
    /// one), and no pair's distance falls below its separation along the state's axis
    /// (`Scratch::bound_axis`) by more than the drop at that axis's rate that way
    /// (`axis_rates`), on straight motions and Béziers, on the test arm and on two bundled arms
    /// among their scenes (7 and 8 joints, where the joints' terms cancel); the state-local rate
    /// is often under half the chain rate, and a rate along the axis often under half the
    /// state-local one (each is what makes it worth its cost).
    #[test]
    fn no_pair_closes_faster_than_its_rate() {
        let load = |scene: &str| {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            RobotModel::new(serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()).unwrap()
        };
        for (model, motions, every) in [(arm(), 300, 1), (load("panda_blocks"), 24, 7), (load("vx300s_clutter"), 24, 5)] {
            assert!(model.pairs.len() >= 6, "{}", model.pairs.len());
            let k = model.njoint();
            let levers = Levers::of(&model);
            let space = Space::of(&model).unwrap();
            let mut s = Scratch::new(&model);
            let mut axes = Axes::new(&model);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
            let (mut tight_wins, mut axis_wins, mut checks, mut measured) = (0, 0, 0, 0);
            let pose =
                |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f64> { (0..k).map(|j| rng.random_range(space.lo[j]..space.hi[j])).collect() };
            for m in 0..motions {
                // (a third of the motions shortened: states nearer one another)
                let (a, b, c) = (pose(&mut rng), pose(&mut rng), pose(&mut rng));
                let shrink = if m % 3 == 0 { 0.2 } else { 1.0 };
                let mut d1 = vec![0.0; k];
                let mut d2 = vec![0.0; k];
                space.delta(&a, &b, &mut d1);
                space.delta(&b, &c, &mut d2);
                d1.iter_mut().chain(d2.iter_mut()).for_each(|x| *x *= shrink);
                let line = Line { a: &a, delta: &d1 };
                let bezier = Bezier { p0: &a, d1: &d1, d2: &d2 };
                for blend in [false, true] {
                    if blend {
                        prepare(&model, &space, levers, &mut axes, &bezier);
                    } else {
                        prepare(&model, &space, levers, &mut axes, &line);
                    }
                    let place = |t: f64, q: &mut [f64]| if blend { space.place(&bezier, t, q) } else { space.place(&line, t, q) };
                    for _ in 0..3 {
                        let t0 = rng.random_range(0.0..1.0);
                        let mut q0 = vec![0.0; k];
                        place(t0, &mut q0);
                        if blend {
                            axes.at(&bezier, t0);
                        } else {
                            axes.at(&line, t0);
                        }
                        s.place(&model, &q0, false);
                        s.forget_axes();
                        let mut d0 = vec![f64::NAN; model.pairs.len()];
                        let mut sep = vec![(f64::NAN, nalgebra::Vector3::zeros()); model.pairs.len()];
                        for p in (0..model.pairs.len()).filter(|p| p % every == m % every) {
                            let d = s.pair_lower_bound(&model, p, f64::INFINITY, f64::INFINITY).unwrap();
                            (d0[p], sep[p]) = (d.max(0.0), (d, s.bound_axis));
                        }
                        let mut rates = vec![None; model.pairs.len()];
                        let mut ways = vec![None; model.pairs.len()];
                        for p in (0..model.pairs.len()).filter(|p| p % every == m % every) {
                            let chain = levers.side_sums(&model, &axes.chain, p);
                            let (local, b) = (local_rate(&model, levers, &s, &mut axes, p), levers.side_sums(&model, &axes.quad, p));
                            tight_wins += (local < 0.5 * chain) as usize;
                            measured += 1;
                            rates[p] = Some([Rate::of_chain(chain), Rate { chain: f64::INFINITY, a: local, b }]);
                            let (d, n) = sep[p];
                            if d > 0.0 && n != nalgebra::Vector3::zeros() {
                                let way = axis_rates(&model, levers, &s, &mut axes, p, &n, local);
                                axis_wins += (way[0].min(way[1]) < 0.5 * local) as usize;
                                ways[p] = Some(way.map(|a| Rate { chain: f64::INFINITY, a, b }));
                            }
                        }
                        for tau in [1e-3, 1e-2, 0.05, 0.2, 0.5] {
                            for sign in [-1.0, 1.0] {
                                let t = t0 + sign * tau;
                                if !(0.0..=1.0).contains(&t) {
                                    continue;
                                }
                                let mut q = vec![0.0; k];
                                place(t, &mut q);
                                s.place(&model, &q, false);
                                s.forget_axes();
                                for (p, forms) in rates.iter().enumerate().filter_map(|(p, r)| r.map(|r| (p, r))) {
                                    let d = s.pair_lower_bound(&model, p, f64::INFINITY, f64::INFINITY).unwrap().max(0.0);
                                    checks += 1;
                                    if let Some(way) = ways[p] {
                                        // (back for `sign` -1, forward for +1)
                                        let rate = way[(sign > 0.0) as usize];
                                        let floor = sep[p].0 - rate.drop(tau) * (1.0 + 1e-6) - 1e-9;
                                        assert!(
                                            d >= floor,
                                            "pair {p} along its axis, blend {blend}, {sign}·{tau}: {d} < {floor} ({rate:?})"
                                        );
                                    }
                                    for (form, rate) in forms.iter().enumerate() {
                                        let allowed = rate.drop(tau) * (1.0 + 1e-6) + 1e-9;
                                        assert!(
                                            (d - d0[p]).abs() <= allowed,
                                            "pair {p} form {form} blend {blend}: |{d} - {}| > {allowed} over {tau} ({rate:?})",
                                            d0[p]
                                        );
                                    }
                                }
                            }
                        }
                    }
                }
            }
            assert!(
                checks > 5000 && tight_wins > measured / 10 && axis_wins > measured / 10,
                "{checks} {measured} {tight_wins} {axis_wins}"
            );
        }
    }

    /// The world's boxes around the test arm are split into clusters of at most `CLUSTER`
    /// (`model/broad.rs`), each a group body whose sphere holds its geoms'; in random poses,
    /// `near_pairs` keeps every pair within its margin plus `MAX_CLEARANCE` (GJK's distance) and
    /// only pairs that pass their own sphere test.
    #[test]
    fn world_clusters_keep_every_pair_that_may_touch() {
        use crate::model::broad::{CLUSTER, MAX_CLEARANCE};
        let model = cluttered_arm();
        let b = &model.broad;
        let world: Vec<usize> =
            (0..model.geoms.len()).filter(|&g| model.geoms[g].body == 0 && !model.geoms[g].shape.is_half_space()).collect();
        let clusters = b.world_clusters(&model.geoms);
        let mut seen = vec![0; model.geoms.len()];
        for c in &clusters {
            assert!(!c.held.is_empty() && c.held.len() <= CLUSTER, "{c:?}");
            for &(g, inside) in &c.held {
                assert!(inside, "world geom {g} outside its cluster's sphere ({:?}, {})", c.centre, c.radius);
                seen[g] += 1;
            }
        }
        assert!(world.iter().all(|&g| seen[g] == 1), "each world geom in one cluster: {seen:?}");
        assert!(clusters.len() >= world.len().div_ceil(CLUSTER), "{} clusters", clusters.len());
        let mut s = Scratch::new(&model);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(14);
        let (mut touching, mut culled) = (0, 0);
        let mut near = Vec::new();
        for _ in 0..2000 {
            let q: Vec<f64> = model.limits.iter().map(|l| rng.random_range(l[0]..l[1])).collect();
            s.place(&model, &q, false);
            near.clear();
            b.near_pairs(&mut s.broad, &mut near);
            for k in 0..model.pairs.len() {
                let kept = near.contains(&(k as u32));
                assert!(!kept || b.may_touch(&s.broad, k), "pair {k} kept without passing its own test");
                s.forget_axes();
                let d = s.pair_lower_bound(&model, k, f64::INFINITY, f64::INFINITY).unwrap();
                if d <= model.pairs[k].margin.max(0.0) + MAX_CLEARANCE + 1e-6 {
                    assert!(kept, "pair {k} at {d} m dropped");
                    touching += 1;
                } else if !kept {
                    culled += 1;
                }
            }
        }
        assert!(touching > 100 && culled > 10000, "{touching} touching, {culled} culled");
    }

    /// Certified motions are clear at every state of a fine sampling; a motion through the box
    /// is blocked at a state that is not; the verdict is the same from a used scratch (on the
    /// arm, and on the arm among boxes; the proof started from either end).
    #[test]
    fn certified_motions_are_clear_between_samples_and_verdicts_do_not_depend_on_history() {
        for order in [Order::EndFirst, Order::MiddleFirst] {
            for model in [arm(), cluttered_arm()] {
                certified_motions_are_clear_between_samples(&model, order);
            }
        }
    }

    fn certified_motions_are_clear_between_samples(model: &RobotModel, order: Order) {
        let space = Space::of(model).unwrap();
        let levers = Levers::of(model);
        let mut ms = MotionScratch::new(model);
        let mut fresh = MotionScratch::new(model);
        let mut s = Scratch::new(model);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (mut certified, mut blocked) = (0, 0);
        for _ in 0..300 {
            let a: Vec<f64> = (0..4).map(|j| rng.random_range(space.lo[j]..space.hi[j])).collect();
            let mut delta: Vec<f64> = (0..4).map(|_| rng.random_range(-0.6..0.6)).collect();
            delta[2] *= 0.1;
            let mut b = vec![0.0; 4];
            space.along(&a, &delta, 1.0, &mut b);
            space.delta(&a, &b, &mut delta);
            let v = certify_motion(model, levers, &space, &a, &delta, 1e-6, order, &mut ms).unwrap();
            assert_eq!(v, certify_motion(model, levers, &space, &a, &delta, 1e-6, order, &mut fresh).unwrap());
            let mut q = vec![0.0; 4];
            match v {
                Motion::Certified => {
                    certified += 1;
                    for i in 0..=400 {
                        space.along(&a, &delta, i as f64 / 400.0, &mut q);
                        assert!(crate::collision::fastpath::certified_pose(model, &q, 1e-6, &mut s).unwrap(), "state {i}");
                    }
                }
                Motion::Blocked(t) => {
                    blocked += 1;
                    space.along(&a, &delta, t, &mut q);
                    assert!(
                        !crate::collision::fastpath::certified_pose(model, &q, 1e-6 * (1.0 + 1e-6), &mut s).unwrap() || {
                            // within GJK's tolerance of the clearance or margin
                            let l = crate::collision::collide::label_pose(
                                model,
                                &q,
                                &mut s,
                                crate::collision::collide::LabelOptions { pairs: false, distance: true },
                                &mut Vec::new(),
                            )
                            .unwrap();
                            l.min_distance <= 0.01 + 1e-7
                        }
                    );
                }
                Motion::Unproven => {}
            }
        }
        assert!(certified > 30 && blocked > 30, "{order:?}: {certified} {blocked}");
    }

    /// Buffers kept between sections (`Spare`) serve only their own model, and whoever used
    /// them before changes no verdict: batches on two models of different sizes, in turn,
    /// each model twice (the second time on the first time's spare buffers), give each motion
    /// the verdict and state count of a fresh scratch.
    #[test]
    fn spare_buffers_serve_their_own_model_and_change_no_verdict() {
        let models = [arm(), cluttered_arm()];
        assert_ne!(models[0].pairs.len(), models[1].pairs.len());
        assert_ne!(models[0].id, models[1].id);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let batches: Vec<(Vec<f64>, Vec<f64>)> = models
            .iter()
            .map(|model| {
                let space = Space::of(model).unwrap();
                let (mut a, mut b) = (Vec::new(), Vec::new());
                for _ in 0..24 {
                    for j in 0..4 {
                        a.push(rng.random_range(space.lo[j]..space.hi[j]));
                        b.push(rng.random_range(space.lo[j]..space.hi[j]));
                    }
                }
                (a, b)
            })
            .collect();
        let fresh: Vec<Verdicts> = models
            .iter()
            .zip(&batches)
            .map(|(model, (a, b))| {
                let space = Space::of(model).unwrap();
                (0..a.len() / 4)
                    .map(|i| {
                        let (s, g) = (&a[i * 4..i * 4 + 4], &b[i * 4..i * 4 + 4]);
                        let mut delta = vec![0.0; 4];
                        space.delta(s, g, &mut delta);
                        let mut ms = MotionScratch::new(model);
                        let v = certify_motion(model, Levers::of(model), &space, s, &delta, 1e-6, Order::EndFirst, &mut ms).unwrap();
                        (v, ms.states)
                    })
                    .collect()
            })
            .collect();
        for _ in 0..2 {
            for ((model, (a, b)), want) in models.iter().zip(&batches).zip(&fresh) {
                for threads in [1, 2] {
                    let got = crate::threads::with_threads(Some(threads), || certify_motions(model, a, b, 1e-6)).unwrap().unwrap();
                    assert_eq!(&got, want, "{threads} threads");
                }
            }
        }
    }

    /// Every pair of a certified motion is covered: the intervals its states' radii prove,
    /// `[t − back, t + fwd]`, join up over `[0, 1]` (that each radius is a bound is
    /// `no_pair_closes_faster_than_its_rate`'s), on lines and blends, from either end.
    #[test]
    fn certified_motions_cover_every_pair_from_either_end() {
        for order in [Order::EndFirst, Order::MiddleFirst] {
            for model in [arm(), cluttered_arm()] {
                let space = Space::of(&model).unwrap();
                let levers = Levers::of(&model);
                let mut ms = MotionScratch::new(&model);
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
                let (mut certified, mut measured) = (0, 0);
                for n in 0..200 {
                    let p0: Vec<f64> = (0..4).map(|j| rng.random_range(space.lo[j] * 0.8..space.hi[j] * 0.8)).collect();
                    let mut d: [Vec<f64>; 2] = std::array::from_fn(|_| (0..4).map(|_| rng.random_range(-0.5..0.5)).collect());
                    d[0][2] *= 0.1;
                    d[1][2] *= 0.1;
                    let v = if n % 2 == 0 {
                        certify_motion(&model, levers, &space, &p0, &d[0], 1e-6, order, &mut ms)
                    } else {
                        certify_curve(&model, levers, &space, &Bezier { p0: &p0, d1: &d[0], d2: &d[1] }, 1e-6, order, &mut ms)
                    };
                    if v.unwrap() != Motion::Certified {
                        continue;
                    }
                    certified += 1;
                    let mut by_pair: Vec<Vec<[f64; 2]>> = vec![Vec::new(); model.pairs.len()];
                    for &(p, t, [back, fwd]) in &ms.axes.covers {
                        by_pair[p].push([t - back, t + fwd]);
                    }
                    for (p, proven) in by_pair.iter_mut().enumerate() {
                        proven.sort_by(|a, b| a[0].total_cmp(&b[0]));
                        let mut reach = 0.0f64;
                        for &[lo, hi] in proven.iter() {
                            if lo > reach + 1e-12 {
                                break;
                            }
                            reach = reach.max(hi);
                        }
                        assert!(reach >= 1.0 - 1e-12, "{order:?}, motion {n}, pair {p}: proven to {reach} by {proven:?}");
                        measured += usize::from(proven.len() > 1);
                    }
                }
                assert!(certified > 30 && measured > 100, "{order:?}: {certified} certified, {measured} pairs measured twice");
            }
        }
    }

    #[test]
    fn certified_blends_are_clear_between_samples() {
        for order in [Order::EndFirst, Order::MiddleFirst] {
            certified_blends_are_clear_between_samples_from(order);
        }
    }

    fn certified_blends_are_clear_between_samples_from(order: Order) {
        let model = arm();
        let space = Space::of(&model).unwrap();
        let levers = Levers::of(&model);
        let mut ms = MotionScratch::new(&model);
        let mut s = Scratch::new(&model);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
        let (mut certified, mut blocked) = (0, 0);
        let mut q = vec![0.0; 4];
        for _ in 0..300 {
            let p0: Vec<f64> = (0..4).map(|j| rng.random_range(space.lo[j] * 0.8..space.hi[j] * 0.8)).collect();
            let mut d1: Vec<f64> = (0..4).map(|_| rng.random_range(-0.4..0.4)).collect();
            let mut d2: Vec<f64> = (0..4).map(|_| rng.random_range(-0.4..0.4)).collect();
            d1[2] *= 0.1;
            d2[2] *= 0.1;
            let curve = Bezier { p0: &p0, d1: &d1, d2: &d2 };
            let v = certify_curve(&model, levers, &space, &curve, 1e-6, order, &mut ms).unwrap();
            match v {
                Motion::Certified => {
                    certified += 1;
                    for i in 0..=400 {
                        space.place(&curve, i as f64 / 400.0, &mut q);
                        assert!(crate::collision::fastpath::certified_pose(&model, &q, 1e-6, &mut s).unwrap(), "state {i}");
                    }
                }
                Motion::Blocked(t) => {
                    blocked += 1;
                    space.place(&curve, t, &mut q);
                    assert!((0.0..=1.0).contains(&t));
                }
                Motion::Unproven => {}
            }
        }
        assert!(certified > 30 && blocked > 30, "{order:?}: {certified} {blocked}");
        // A straight Bézier (`d₁ = d₂`) is the straight motion of twice its length: the same verdict.
        for _ in 0..100 {
            let a: Vec<f64> = (0..4).map(|j| rng.random_range(space.lo[j] * 0.8..space.hi[j] * 0.8)).collect();
            let d: Vec<f64> = (0..4).map(|_| rng.random_range(-0.2..0.2)).collect();
            let twice: Vec<f64> = d.iter().map(|x| 2.0 * x).collect();
            let line = certify_motion(&model, levers, &space, &a, &twice, 1e-6, order, &mut ms).unwrap();
            let blend = certify_curve(&model, levers, &space, &Bezier { p0: &a, d1: &d, d2: &d }, 1e-6, order, &mut ms).unwrap();
            assert_eq!(line == Motion::Certified, blend == Motion::Certified);
        }
    }

    /// One batch of lines and blends (`certify_given`) gives each motion the verdict, and the
    /// states, of the certificate run on it alone (`certify_curve` of the line or the Bézier
    /// taken as given), in order (lines, then blends), on one thread and two; `certify_as_given`
    /// of either kind alone agrees; an empty kind is no motion; bad arrays are refused. From
    /// either end.
    #[test]
    fn lines_and_blends_in_one_batch_are_the_motions_alone() {
        for order in [Order::EndFirst, Order::MiddleFirst] {
            lines_and_blends_in_one_batch_are_the_motions_alone_from(order);
        }
    }

    fn lines_and_blends_in_one_batch_are_the_motions_alone_from(order: Order) {
        use crate::threads::with_threads;
        let model = arm();
        let k = model.njoint();
        let space = Space::of(&model).unwrap();
        let given = Space { lo: vec![f64::NEG_INFINITY; k], hi: vec![f64::INFINITY; k], ..space.clone() };
        let levers = Levers::of(&model);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        let mut rows =
            |n: usize| -> Vec<f64> { (0..n * k).map(|x| rng.random_range(space.lo[x % k] * 0.8..space.hi[x % k] * 0.8)).collect() };
        let (l0, l1) = (rows(23), rows(23));
        let (b0, b2) = (rows(17), rows(17));
        let b1: Vec<f64> = b0.iter().zip(&b2).map(|(a, c)| 0.5 * (a + c) + 0.1).collect();
        let diff = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| b - a).collect::<Vec<f64>>();
        let mut ms = MotionScratch::new(&model);
        let mut alone = |curve: &dyn Fn(&mut MotionScratch) -> Motion| {
            let m = curve(&mut ms);
            format!("{m:?} {}", ms.states)
        };
        let lines: Vec<String> = (0..23)
            .map(|i| {
                let (a, g) = (&l0[i * k..(i + 1) * k], &l1[i * k..(i + 1) * k]);
                let delta = diff(a, g);
                alone(&|ms| certify_curve(&model, levers, &given, &Line { a, delta: &delta }, 1e-6, order, ms).unwrap())
            })
            .collect();
        let blends: Vec<String> = (0..17)
            .map(|i| {
                let r = i * k..(i + 1) * k;
                let (d1, d2) = (diff(&b0[r.clone()], &b1[r.clone()]), diff(&b1[r.clone()], &b2[r.clone()]));
                alone(&|ms| {
                    certify_curve(&model, levers, &given, &Bezier { p0: &b0[r.clone()], d1: &d1, d2: &d2 }, 1e-6, order, ms).unwrap()
                })
            })
            .collect();
        let verdicts = |v: &Verdicts| v.iter().map(|(m, n)| format!("{m:?} {n}")).collect::<Vec<_>>();
        let kinds: std::collections::HashSet<&str> = lines.iter().chain(&blends).map(|v| &v[..4]).collect();
        assert!(kinds.len() >= 2, "the motions should not all end alike: {kinds:?}");
        for threads in [1, 2] {
            let (l, b) = with_threads(Some(threads), || certify_given(&model, [&l0, &l1], [&b0, &b1, &b2], 1e-6, order)).unwrap().unwrap();
            assert_eq!(verdicts(&l), lines, "{threads} threads");
            assert_eq!(verdicts(&b), blends, "{threads} threads");
        }
        assert_eq!(verdicts(&certify_as_given(&model, &l0, None, &l1, 1e-6, order).unwrap()), lines);
        assert_eq!(verdicts(&certify_as_given(&model, &b0, Some(&b1), &b2, 1e-6, order).unwrap()), blends);
        let (l, b) = certify_given(&model, [&[], &[]], [&b0, &b1, &b2], 1e-6, order).unwrap();
        assert!(l.is_empty() && verdicts(&b) == blends);
        let err = |r: Result<(Verdicts, Verdicts)>| r.unwrap_err().to_string();
        assert!(err(certify_given(&model, [&l0, &l1[..2 * k]], [&[], &[], &[]], 1e-6, order)).contains("differ in shape"));
        assert!(err(certify_given(&model, [&l0, &l1], [&[], &[], &[]], 0.0, order)).contains("clearance"));
        assert!(certify_as_given(&model, &[], None, &[], 1e-6, order).is_err());
    }

    /// `first_certified` gives each task the first of its motions `certify_as_given` certifies,
    /// taken in turn (a skipped motion never, a task without one none), on one thread and two;
    /// a bad clearance is refused.
    #[test]
    fn first_certified_is_each_tasks_motions_certified_in_turn() {
        use crate::threads::with_threads;
        let model = arm();
        let k = model.njoint();
        let space = Space::of(&model).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // 30 tasks of up to four motions each (start, goal, whether to certify it), some skipped
        type Task = Vec<(Vec<f64>, Vec<f64>, bool)>;
        let tasks: Vec<Task> = (0..30)
            .map(|_| {
                (0..rng.random_range(0..5))
                    .map(|_| {
                        let mut pose = || (0..k).map(|j| rng.random_range(space.lo[j] * 0.8..space.hi[j] * 0.8)).collect::<Vec<f64>>();
                        (pose(), pose(), rng.random_bool(0.8))
                    })
                    .collect()
            })
            .collect();
        let want: Vec<Option<usize>> = tasks
            .iter()
            .map(|t| {
                t.iter().position(|(a, g, given)| {
                    *given && certify_as_given(&model, a, None, g, 1e-6, Order::MiddleFirst).unwrap()[0].0 == Motion::Certified
                })
            })
            .collect();
        assert!(want.iter().any(|w| w.is_none()) && want.iter().any(|w| w.is_some_and(|n| n > 0)), "{want:?}");
        let motion = |i: usize, n: usize, a: &mut [f64], g: &mut [f64]| {
            let (sa, sg, given) = tasks[i].get(n)?;
            a.copy_from_slice(sa);
            g.copy_from_slice(sg);
            Some(*given)
        };
        for threads in [1, 2] {
            let got = with_threads(Some(threads), || {
                first_certified(&model, tasks.len(), &|i| format!("task {i}"), 1e-6, Order::MiddleFirst, motion)
            });
            assert_eq!(got.unwrap().unwrap(), want, "{threads} threads");
        }
        assert!(first_certified(&model, 3, &|i| format!("task {i}"), 0.0, Order::MiddleFirst, motion).is_err());
    }
}
