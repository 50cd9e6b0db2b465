//! Global paths over the exact labeller: RRT-Connect in joint space, then shortcutting.
//!
//! The configuration space is a product of intervals (limited joints) and circles (continuous
//! hinges, SO(2)): differences on a circle take the short arc, by the same function as
//! `interpolate_so2` (`angles::wrap`: a half turn moves the negative way), and states and
//! waypoints on a circle are wrapped into `[-π, π)` by it too, so a path's segments are exactly
//! the motions the SO(2) interpolation (and the certification in Python) will replay.
//!
//! States are checked by the booleans-only fast path (`collision/fastpath.rs`: the labeller's answer, bit
//! for bit, stopping at the first pair in contact; four states at a time where a batch allows,
//! `fastpath::first_colliding`). A state whose pair the narrow phase cannot
//! decide (`collision/collide.rs`: never "free") ends the call with an error naming the state and the pair.
//!
//! An edge `a → b` is free when every state `a + (i/n)·Δ`, `i = 1..n`, is free with
//! `n = ceil(max_k |Δ_k| / resolution)`: no joint moves more than `resolution` between two
//! checked states. States are checked coarse-to-fine (the end, then midpoints breadth-first) in
//! fixed batches; a batch is checked in parallel when it is large. Batches depend only on `n`,
//! never on the thread count, so the checks made, the tree grown and the path returned are the
//! same for any number of threads (only `seconds` differs, and a run cut by `max_time`).
//!
//! RRT-Connect (Kuffner & LaValle 2000): two trees, from start and goal; each iteration extends
//! one toward a uniform sample by at most `range` (L2, radians/metres), or a quarter of it where
//! the full step is blocked, then greedily connects the other tree to the new node; the trees
//! swap roles every iteration.
//!
//! Continuous edges: explore cheaply, prove what is returned. The search and the shortcuts check
//! edges sampled at `EXPLORE` (0.05 rad) only; the path they find is then proven: each interior
//! waypoint certified (`certified_pose`, else dropped) and each segment by the continuous
//! certificate (`motion::certify_motion`), a segment that fails replaced by a search between
//! its ends whose every edge is proven. The segments are proven side by side on the call's
//! threads (`proven_segments`), each whole, as `certify_motions` proves it: every verdict, and
//! the path, are the same on any number of threads, and `certify_motions` of the returned path
//! agrees with it. What is returned is proven exactly as before; the search
//! no longer pays for proofs of the edges it throws away (on MotionBenchMaker's Panda problems,
//! most of its time). Where the repairs find nothing, a search that proves every edge runs from
//! the start with the time left. A sampled search that finds nothing is the answer: a proving
//! one accepts fewer edges.

use std::sync::{Mutex, PoisonError};
use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::collision::collide::{Scratch, Scratch4};
use crate::collision::fastpath::{certified_pose_with, collides_pose_with, first_colliding, First};
use crate::error::{invalid_input, Result};
use crate::joints::angles::wrap;
use crate::joints::couplings::FEASIBLE_TOL;
use crate::model::broad::{check_clearance, MAX_CLEARANCE};
use crate::model::RobotModel;
use crate::planning::motion::{certify_motion, prove_apart, Levers, Motion, MotionScratch, Order, Space, Spare};
use crate::threads::map_shared;

/// What a planning call may spend and how finely it checks edges.
#[derive(Clone, Debug)]
pub struct PlanOptions {
    /// Largest joint move between two checked states (radians / metres).
    pub resolution: f64,
    /// Wall-clock budget in seconds (planning and shortcutting together).
    pub max_time: f64,
    /// Seed of the sampler (and of the shortcut pairs).
    pub seed: u64,
    /// Longest tree extension (L2 in joint space); 0 picks `DEFAULT_RANGE` × the space's diagonal.
    pub range: f64,
    /// Deterministic budget: tree-extension iterations.
    pub max_iterations: usize,
    /// Shortcut attempts on the found path.
    pub shortcut_rounds: usize,
    /// The answer is verified `verify` times finer than `resolution` (segments that fail are
    /// re-planned at that resolution); 1 turns verification off. Sampled edges only.
    pub verify: usize,
    /// Edges are certified continuously (`planning/motion.rs`: every pair above `max(margin,
    /// clearance)` at every state of the edge, proven); false: sampled at `resolution`.
    pub continuous: bool,
    /// Metres, in (0, `MAX_CLEARANCE`]: the distance every pair keeps on a continuous edge.
    pub clearance: f64,
    /// Joints held where they are (empty: none): the start and goal must agree on them, and no
    /// state of the search moves them (a gripper's jaw the task does not open).
    pub held: Vec<bool>,
}

impl Default for PlanOptions {
    fn default() -> Self {
        Self {
            resolution: 0.01,
            max_time: 10.0,
            seed: 0,
            range: 0.0,
            max_iterations: 200_000,
            shortcut_rounds: 200,
            verify: 10,
            continuous: true,
            clearance: MAX_CLEARANCE,
            held: Vec::new(),
        }
    }
}

/// Why a plan ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlanStatus {
    /// The straight (SO(2)) path is free.
    Direct,
    /// RRT-Connect joined the trees.
    Connected,
    /// `max_time` ran out first.
    TimeOut,
    /// `max_iterations` ran out first.
    IterationLimit,
}

/// A plan: waypoints `(M, K)` row-major (start first, goal last) when found.
#[derive(Clone, Debug)]
pub struct PlanResult {
    pub path: Vec<f64>,
    pub status: PlanStatus,
    /// Poses labelled (every state of every checked batch).
    pub checks: u64,
    pub iterations: usize,
    pub tree_sizes: [usize; 2],
    /// Waypoints before shortcutting.
    pub raw_waypoints: usize,
    pub seconds: f64,
    /// Of `seconds`, the time spent shortcutting the path the search found.
    pub shortcut_seconds: f64,
}

impl PlanResult {
    pub fn found(&self) -> bool {
        matches!(self.status, PlanStatus::Direct | PlanStatus::Connected)
    }
}

/// A uniform state of the space's box, its dependent joints then put on their couplings.
fn sample(space: &Space, rng: &mut ChaCha8Rng, out: &mut [f64]) {
    for ((v, lo), hi) in out.iter_mut().zip(&space.lo).zip(&space.hi) {
        *v = lo + (hi - lo) * rng.random::<f64>();
    }
    space.couplings.apply(out);
}

/// States of an edge in the order they are checked: `n` (the end) first, then midpoints of
/// `[0, n]` breadth-first, so a collision anywhere is met after few checks.
fn check_order(n: usize) -> Vec<usize> {
    let mut order = Vec::with_capacity(n);
    order.push(n);
    let mut queue = std::collections::VecDeque::from([(0usize, n)]);
    while let Some((l, h)) = queue.pop_front() {
        if h - l < 2 {
            continue;
        }
        let m = l + (h - l) / 2;
        order.push(m);
        queue.push_back((l, m));
        queue.push_back((m, h));
    }
    order
}

/// Batch sizes over an edge's ordered states: the end and the first midpoints first (the end
/// settles most blocked edges of a tree search), then small ones (early exit), then wide
/// (parallel). A batch checked on one thread places its states four at a time
/// (`fastpath::first_colliding`: forward kinematics, spheres and the near pairs' box tests in
/// lanes): 0.88-0.89 of the time per MotionBenchMaker problem (paired), the same paths, against
/// one at a time. The first batch too: four states in lanes cost less than the end state alone
/// on the scalar path (the 30 median MotionBenchMaker problems' plans, callgrind: 326.4 → 319.1 M
/// instructions against a first batch of the end alone; `[4, 16, 64, 256]` 319.5 M).
const BATCHES: [usize; 5] = [4, 4, 16, 64, 256];
/// Continuous edges are first tried for a cheap refutation at up to `PRECHECK_STATES` states of
/// a grid this fine (radians / metres), coarse to fine. The verdict is the certificate's either
/// way (a refuted edge has a state in contact, which no certificate passes), so these set cost
/// only: 0.1 and 8 against 0.05 and 16, the same paths on `benches/planning.py`'s problems, and
/// medians 8% lower on the Shadow Hand, level elsewhere (0.05 with 4, 0.1 with 4, 6 or 16, 0.2
/// with 4 and 0.1 with 2 tried).
const PRECHECK_STEP: f64 = 0.1;
const PRECHECK_STATES: usize = 8;
/// Continuous planning explores with edges sampled this finely (radians / metres) and proves
/// only the path it returns (`explore`, `prove`).
const EXPLORE: f64 = 0.05;
/// The default range: this share of the joint space's diagonal.
const DEFAULT_RANGE: f64 = 0.1;
/// A blocked extension tries again this share of the range toward the same target (`extend`).
const SHORT_STEP: f64 = 0.25;
/// Batches at least this large are checked in parallel.
const PARALLEL_FROM: usize = 64;

/// Exact collision checks for one planning call.
struct Checker<'m> {
    model: &'m RobotModel,
    space: Space,
    resolution: f64,
    scratch: Scratch,
    /// Four states placed at a time, for the sampled edges' later batches.
    lanes: Scratch4,
    /// `check_order(n)` by `n`, kept for `n <= KEPT_ORDERS` (an exploring search's edges have
    /// tens of states: built once per call, not once per edge; 260 kB at most).
    orders: Vec<Option<std::sync::Arc<[usize]>>>,
    checks: u64,
    /// Continuous edges: the certificate's levers, clearance and buffers.
    motion: Option<Continuous<'m>>,
}

/// What a `Checker` certifies continuous edges with: the model's levers, the clearance, and the
/// certificate's buffers (taken on first use, `Spare`: spare ones of this model where there are
/// any; lent to `proven_segments`' first worker).
struct Continuous<'m> {
    levers: Levers<'m>,
    clearance: f64,
    buffers: Option<Spare>,
}

/// A `proven_segments` worker's certificate buffers: lent from its checker where they were free
/// (else taken, `Spare`), and given back there, if none were, when the worker is done with them
/// (else to the spares).
struct Lent<'a> {
    buffers: Option<Spare>,
    home: &'a Mutex<Option<Spare>>,
}

impl Drop for Lent<'_> {
    fn drop(&mut self) {
        let mut home = self.home.lock().unwrap_or_else(PoisonError::into_inner);
        if home.is_none() {
            *home = self.buffers.take();
        }
    }
}

/// The longest edge (in states) whose check order a `Checker` keeps.
const KEPT_ORDERS: usize = 256;

impl<'m> Checker<'m> {
    /// `check_order(n)`, kept when short.
    fn order(&mut self, n: usize) -> std::sync::Arc<[usize]> {
        if n > KEPT_ORDERS {
            return check_order(n).into();
        }
        if self.orders.len() <= n {
            self.orders.resize(n + 1, None);
        }
        self.orders[n].get_or_insert_with(|| check_order(n).into()).clone()
    }

    /// Whether `q` (the call's `what`: start or goal) is free.
    fn free(&mut self, q: &[f64], what: &str) -> Result<bool> {
        self.checks += 1;
        match collides_pose_with(self.model, q, &mut self.scratch, First::LastHit) {
            Ok(c) => Ok(!c),
            Err(e) => Err(e.error(self.model, format!("{what} {q:?}"))),
        }
    }

    /// Whether the SO(2) segment `a → b` is free: certified continuously, or at `resolution`
    /// (`a` is taken as free).
    fn edge_free(&mut self, a: &[f64], b: &[f64]) -> Result<bool> {
        let k = a.len();
        let mut d = vec![0.0; k];
        self.space.delta(a, b, &mut d);
        let span = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if self.motion.is_some() {
            // Refuted cheaply first: the booleans-only fast path at a few states, coarse to
            // fine (a blocked edge is the common case in a tree search, and a state in contact
            // usually stops after one pair test). Only a refutation is taken from it.
            let n = ((span / PRECHECK_STEP).ceil() as usize).max(1);
            let mut q = vec![0.0; k];
            for &i in self.order(n).iter().take(PRECHECK_STATES) {
                self.space.along(a, &d, i as f64 / n as f64, &mut q);
                self.checks += 1;
                match collides_pose_with(self.model, &q, &mut self.scratch, First::LastHit) {
                    Ok(false) => {}
                    Ok(true) => return Ok(false),
                    Err(e) => return Err(e.error(self.model, format!("planning state {q:?}"))),
                }
            }
        }
        if let Some(c) = &mut self.motion {
            let model = self.model;
            let ms = c.buffers.get_or_insert_with(|| Spare::take(model));
            let (certified, states) = certified_edge(model, c.levers, &self.space, a, b, &d, c.clearance, ms)?;
            self.checks += states as u64;
            return Ok(certified);
        }
        let n = ((span / self.resolution).ceil() as usize).max(1);
        crate::budget::check("the states of one edge (its length / resolution)", &[n, 2], 8)?;
        let order = self.order(n);
        let mut start = 0;
        let mut b_idx = 0;
        while start < order.len() {
            let size = BATCHES[b_idx.min(BATCHES.len() - 1)];
            b_idx += 1;
            let batch = &order[start..(start + size).min(order.len())];
            start += batch.len();
            self.checks += batch.len() as u64;
            let state = |i: usize, q: &mut [f64]| {
                if i == n {
                    q.copy_from_slice(b);
                } else {
                    self.space.along(a, &d, i as f64 / n as f64, q);
                }
            };
            let model = self.model;
            // The first state of the batch, in check order, that collides or cannot be decided
            // (the first either way, so the answer does not depend on the thread count).
            let stops = |(_, r): &(usize, std::result::Result<bool, _>)| *r != Ok(false);
            let first = if batch.len() >= PARALLEL_FROM {
                crate::threads::in_pool(|| {
                    batch
                        .par_iter()
                        .map_init(
                            || (Scratch::new(model), vec![0.0; k]),
                            |(s, q), &i| {
                                state(i, q);
                                (i, collides_pose_with(model, q, s, First::LastHit))
                            },
                        )
                        .find_first(stops)
                })
            } else {
                // (four states at a time, the first batch too: its end state usually settles a
                // blocked edge, and three more cost less beside it than it costs alone)
                let mut states = vec![0.0; batch.len() * k];
                for (&i, q) in batch.iter().zip(states.chunks_exact_mut(k)) {
                    state(i, q);
                }
                first_colliding(model, &states, &mut self.lanes, &mut self.scratch).map(|(at, r)| (batch[at], r))
            };
            match first {
                None => {}
                Some((_, Ok(_))) => return Ok(false),
                Some((i, Err(e))) => {
                    let mut q = vec![0.0; k];
                    state(i, &mut q);
                    return Err(e.error(model, format!("planning state {q:?}")));
                }
            }
        }
        Ok(true)
    }
}

/// A tree's node nearest a target (`Tree::nearest`): its index, distance and squared
/// distance, over the tree's first `seen` nodes.
#[derive(Clone, Copy, Debug)]
struct Nearest {
    node: usize,
    dist: f64,
    squared: f64,
    seen: usize,
}

/// One search tree: nodes row-major, each with its parent (`usize::MAX` at the root).
#[derive(Clone)]
struct Tree {
    nodes: Vec<f64>,
    parent: Vec<usize>,
    k: usize,
}

impl Tree {
    fn new(root: &[f64]) -> Self {
        Tree { nodes: root.to_vec(), parent: vec![usize::MAX], k: root.len() }
    }

    fn node(&self, i: usize) -> &[f64] {
        &self.nodes[i * self.k..(i + 1) * self.k]
    }

    fn len(&self) -> usize {
        self.parent.len()
    }

    /// The first of the nodes nearest `q` (the root of `Space::squared`), and that distance, going on
    /// from `known` (the same target's scan of this tree's first `known.seen` nodes: the
    /// nodes added since are scanned alone) where given.
    ///
    /// The same node and distance as the root of `squared` to every node, the first of equals kept:
    /// squared distances decide first (the square root is monotonic, so a square at or above
    /// the best one's is never nearer), and a smaller square is nearer only where its root is
    /// (two squares can share a root), which is computed then alone.
    fn nearest(&self, space: &Space, q: &[f64], known: Option<Nearest>) -> Nearest {
        let mut best = known.unwrap_or(Nearest { node: 0, dist: f64::INFINITY, squared: f64::INFINITY, seen: 0 });
        let wraps = space.wraps.iter().any(|&w| w);
        for (i, node) in self.nodes.chunks_exact(self.k).enumerate().skip(best.seen) {
            // (`Space::squared`'s sum, in the same order, without its per-joint wrap test
            // where no joint wraps)
            let squared = if wraps { space.squared(node, q) } else { node.iter().zip(q).fold(0.0, |s, (a, b)| s + (b - a) * (b - a)) };
            if squared < best.squared {
                let dist = squared.sqrt();
                if dist < best.dist {
                    best = Nearest { node: i, dist, squared, seen: 0 };
                }
            }
        }
        best.seen = self.len();
        best
    }

    fn push(&mut self, q: &[f64], parent: usize) -> usize {
        self.nodes.extend_from_slice(q);
        self.parent.push(parent);
        self.len() - 1
    }

    /// Nodes from `i` up to the root.
    fn branch(&self, mut i: usize) -> Vec<usize> {
        let mut out = vec![i];
        while self.parent[i] != usize::MAX {
            i = self.parent[i];
            out.push(i);
        }
        out
    }
}

enum Extend {
    Trapped,
    Advanced(usize),
    Reached(usize),
}

/// Grows `tree` from its node nearest `target` by at most `range` toward it. `known`: the
/// last call's nearest node to the same target (RRT-Connect's connect steps), updated.
fn extend(tree: &mut Tree, checker: &mut Checker, target: &[f64], range: f64, known: &mut Option<Nearest>) -> Result<Extend> {
    let nearest = tree.nearest(&checker.space, target, known.take());
    *known = Some(nearest);
    let (near, dist) = (nearest.node, nearest.dist);
    let from = tree.node(near).to_vec();
    let mut q = target.to_vec();
    let reached = dist <= range;
    if !reached {
        let mut d = vec![0.0; q.len()];
        checker.space.delta(&from, target, &mut d);
        checker.space.along(&from, &d, range / dist, &mut q);
    }
    if checker.edge_free(&from, &q)? {
        let i = tree.push(&q, near);
        return Ok(if reached { Extend::Reached(i) } else { Extend::Advanced(i) });
    }
    // Blocked: a step of a quarter of the range toward the same target (a tree whose root is in
    // a narrow place, a goal between shelves, grows where steps of the full range never pass).
    let short = SHORT_STEP * range;
    if dist <= short {
        return Ok(Extend::Trapped);
    }
    let mut d = vec![0.0; q.len()];
    checker.space.delta(&from, target, &mut d);
    checker.space.along(&from, &d, short / dist, &mut q);
    if !checker.edge_free(&from, &q)? {
        return Ok(Extend::Trapped);
    }
    Ok(Extend::Advanced(tree.push(&q, near)))
}

/// Plans a collision-free path from `start` to `goal` (length K each, free, within limits).
///
/// `ranges` are the sampling ranges (`RobotModel::sampling_ranges`); `continuous` marks the
/// wrapping joints. Runs on rayon's current pool for wide edge batches.
pub fn plan_path(model: &RobotModel, start: &[f64], goal: &[f64], opts: &PlanOptions) -> Result<PlanResult> {
    let clock = Instant::now();
    let k = model.njoint();
    if start.len() != k || goal.len() != k {
        return invalid_input(format!("start and goal must have {k} joints; got {} and {}", start.len(), goal.len()));
    }
    if start.iter().chain(goal).any(|v| !v.is_finite()) {
        return invalid_input("start and goal must be finite");
    }
    if !(opts.resolution > 0.0 && opts.resolution.is_finite()) {
        return invalid_input(format!("resolution must be a positive length; got {}", opts.resolution));
    }
    if opts.max_time.is_nan() || opts.max_time <= 0.0 {
        return invalid_input(format!("max_time must be positive seconds; got {}", opts.max_time));
    }
    if !(opts.range >= 0.0 && opts.range.is_finite()) {
        return invalid_input(format!("range must be >= 0; got {}", opts.range));
    }
    if opts.continuous {
        check_clearance(opts.clearance)?;
    }
    // The model's proofs first (once per model, as the labelling entry points make them), so
    // that the search's states skip the pairs proven apart from a new scene's first call on,
    // not only after its first certified motion.
    prove_apart(model);
    let space = Space::of(model)?;
    let diagonal = space.lo.iter().zip(&space.hi).map(|(l, h)| (h - l) * (h - l)).sum::<f64>().sqrt();
    let range = if opts.range > 0.0 { opts.range } else { DEFAULT_RANGE * diagonal };
    let motion = opts.continuous.then(|| Continuous { levers: Levers::of(model), clearance: opts.clearance, buffers: None });
    let mut checker = Checker {
        model,
        space,
        resolution: opts.resolution,
        scratch: Scratch::new(model),
        lanes: Scratch4::new(model),
        orders: Vec::new(),
        checks: 0,
        motion,
    };
    for (q, what) in [(start, "start"), (goal, "goal")] {
        let sp = &checker.space;
        for (j, &v) in q.iter().enumerate() {
            if !sp.wraps[j] && (v < sp.lo[j] - 1e-9 || v > sp.hi[j] + 1e-9) {
                return invalid_input(format!("{what}[{j}] = {v} is outside the joint's limits"));
            }
        }
        let off = model.couplings().residual(q);
        if off > FEASIBLE_TOL {
            return invalid_input(format!(
                "{what} is {off:e} off its joint couplings (equalities): the robot cannot take it; put it on them first (Robot.project)"
            ));
        }
        if !checker.free(q, what)? {
            return invalid_input(format!("{what} collides"));
        }
        if opts.continuous {
            let clear = certified_pose_with(model, q, opts.clearance, &mut checker.scratch, First::LastHit)
                .map_err(|e| e.error(model, format!("{what} {q:?}")))?;
            if !clear {
                return invalid_input(format!(
                    "{what} is free but within {} m of contact: no motion from it can be certified; plan with sampled edges",
                    opts.clearance
                ));
            }
        }
    }
    let start: Vec<f64> = start.iter().zip(&checker.space.wraps).map(|(&v, &w)| if w { wrap(v) } else { v }).collect();
    let goal: Vec<f64> = goal.iter().zip(&checker.space.wraps).map(|(&v, &w)| if w { wrap(v) } else { v }).collect();
    if !opts.held.is_empty() {
        if opts.held.len() != k {
            return invalid_input(format!("held has {} entries for {k} joints", opts.held.len()));
        }
        for j in (0..k).filter(|&j| opts.held[j]) {
            if start[j] != goal[j] {
                return invalid_input(format!("joint {j} is held but start ({}) and goal ({}) differ in it", start[j], goal[j]));
            }
            // the sampler draws lo + (hi - lo) u: a held joint's every state is its start value
            checker.space.lo[j] = start[j];
            checker.space.hi[j] = start[j];
        }
    }
    let mut shortcut_seconds = 0.0;
    let finish = |path: Vec<f64>, status, checks, iterations, tree_sizes, raw, shortcut_seconds| PlanResult {
        path,
        status,
        checks,
        iterations,
        tree_sizes,
        raw_waypoints: raw,
        seconds: clock.elapsed().as_secs_f64(),
        shortcut_seconds,
    };
    // a stop asked for (Ctrl-C, `cancel`) ends the search as the time budget would; the binding
    // that asked raises instead of returning what was found
    let deadline = |c: &Instant| c.elapsed().as_secs_f64() > opts.max_time || crate::cancel::requested();
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    if opts.continuous {
        // Explore cheaply, prove what is returned (module docs): the search and the shortcuts
        // check edges at `EXPLORE` only; the answer is then proven waypoint by waypoint and
        // segment by segment, a segment that fails repaired by a search that proves every edge.
        // Where no proven answer comes of it, the search below proves every edge from the start.
        let motion = checker.motion.take();
        checker.resolution = EXPLORE;
        let explored = explore(&mut checker, &mut rng, &start, &goal, range, opts, || deadline(&clock))?;
        checker.motion = motion;
        let mut found = match explored {
            Ok(found) => found,
            Err(search) => return Ok(finish(Vec::new(), search.status, checker.checks, search.iterations, search.sizes, 0, 0.0)),
        };
        if let Some(Proven { path, repairs }) = prove(&mut checker, &mut rng, &found.path, range, opts, || deadline(&clock))? {
            if let Some(r) = repairs {
                // (repaired: the straight path was not the answer, and the repairs' trees met)
                found.status = PlanStatus::Connected;
                found.iterations += r.iterations;
                found.sizes = [found.sizes[0] + r.sizes[0], found.sizes[1] + r.sizes[1]];
            }
            let (checks, shortcut) = (checker.checks, found.shortcut_seconds);
            return Ok(finish(path.concat(), found.status, checks, found.iterations, found.sizes, found.raw, shortcut));
        }
    }
    let (path, status, iterations, sizes, raw) = if checker.edge_free(&start, &goal)? {
        (vec![start.clone(), goal.clone()], PlanStatus::Direct, 0, [1, 1], 2)
    } else {
        let search = rrt_connect(&mut checker, &mut rng, &start, &goal, range, opts.max_iterations, || deadline(&clock))?;
        let Some(order) = search.path else {
            return Ok(finish(Vec::new(), search.status, checker.checks, search.iterations, search.sizes, 0, 0.0));
        };
        let raw = order.len();
        let searched = clock.elapsed().as_secs_f64();
        let path = shortcut(order, &mut checker, &mut rng, opts.shortcut_rounds, || deadline(&clock))?;
        shortcut_seconds = clock.elapsed().as_secs_f64() - searched;
        (path, search.status, search.iterations, search.sizes, raw)
    };
    if opts.verify <= 1 || opts.continuous {
        return Ok(finish(path.concat(), status, checker.checks, iterations, sizes, raw, shortcut_seconds));
    }
    // Verification: every segment of the answer again, `verify` times finer. Search and
    // shortcutting decide edges at `resolution`; a thin feature or a grazing contact can slip
    // between two of its samples. A segment that fails is replaced by a search between its ends
    // at the fine resolution (its own shortcutting included), so what is returned is free at the
    // fine resolution, or nothing is.
    checker.resolution = opts.resolution / opts.verify as f64;
    let mut out = vec![path[0].clone()];
    let mut iterations = iterations;
    for w in path.windows(2) {
        if checker.edge_free(&w[0], &w[1])? {
            out.push(w[1].clone());
            continue;
        }
        let budget = opts.max_iterations.saturating_sub(iterations).max(1);
        let sub = rrt_connect(&mut checker, &mut rng, &w[0], &w[1], range, budget, || deadline(&clock))?;
        iterations += sub.iterations;
        let Some(sub_path) = sub.path else {
            return Ok(finish(Vec::new(), sub.status, checker.checks, iterations, sizes, raw, shortcut_seconds));
        };
        let sub_path = shortcut(sub_path, &mut checker, &mut rng, opts.shortcut_rounds, || deadline(&clock))?;
        out.extend(sub_path.into_iter().skip(1));
    }
    Ok(finish(out.concat(), status, checker.checks, iterations, sizes, raw, shortcut_seconds))
}

/// What the exploring search found (`plan_path`, continuous: edges checked at `EXPLORE`).
struct Explored {
    path: Vec<Vec<f64>>,
    status: PlanStatus,
    iterations: usize,
    sizes: [usize; 2],
    raw: usize,
    shortcut_seconds: f64,
}

/// The straight path, else RRT-Connect, then shortcuts, all with `checker`'s sampled edges (its
/// `motion` taken out by the caller): `Err` with the search's status and iterations when it found
/// nothing within its budget (a search that proves every edge accepts fewer edges: it would not).
fn explore(
    checker: &mut Checker,
    rng: &mut ChaCha8Rng,
    start: &[f64],
    goal: &[f64],
    range: f64,
    opts: &PlanOptions,
    out_of_time: impl Fn() -> bool + Copy,
) -> Result<std::result::Result<Explored, Search>> {
    if checker.edge_free(start, goal)? {
        let path = vec![start.to_vec(), goal.to_vec()];
        return Ok(Ok(Explored { path, status: PlanStatus::Direct, iterations: 0, sizes: [1, 1], raw: 2, shortcut_seconds: 0.0 }));
    }
    let mut search = rrt_connect(checker, rng, start, goal, range, opts.max_iterations, out_of_time)?;
    let Some(order) = search.path.take() else {
        return Ok(Err(search));
    };
    let raw = order.len();
    let clock = Instant::now();
    let path = shortcut(order, checker, rng, opts.shortcut_rounds, out_of_time)?;
    let shortcut_seconds = clock.elapsed().as_secs_f64();
    Ok(Ok(Explored { path, status: search.status, iterations: search.iterations, sizes: search.sizes, raw, shortcut_seconds }))
}

/// A path every segment of which is proven (`prove`), and the search its repairs made.
struct Proven {
    path: Vec<Vec<f64>>,
    repairs: Option<Search>,
}

/// `path` (found with sampled edges) proven: its waypoints certified (`certified_pose`) and its
/// segments by the continuous certificate (`checker.motion`); a waypoint that is not is dropped,
/// and a segment that is not proven is replaced by a search between its ends that proves every
/// edge (and its shortcuts). `Some`, every segment proven (the repairs' search: their iterations
/// and trees' nodes, summed; none when nothing was repaired); None when a repair finds nothing
/// within the budget.
fn prove(
    checker: &mut Checker,
    rng: &mut ChaCha8Rng,
    path: &[Vec<f64>],
    range: f64,
    opts: &PlanOptions,
    out_of_time: impl Fn() -> bool + Copy,
) -> Result<Option<Proven>> {
    let Some(clearance) = checker.motion.as_ref().map(|m| m.clearance) else {
        return Ok(None);
    };
    // start and goal are certified by the caller; interior waypoints only free at EXPLORE
    let mut kept = vec![path[0].clone()];
    for q in &path[1..path.len() - 1] {
        checker.checks += 1;
        let clear = certified_pose_with(checker.model, q, clearance, &mut checker.scratch, First::LastHit)
            .map_err(|e| e.error(checker.model, format!("planning state {q:?}")))?;
        if clear {
            kept.push(q.clone());
        }
    }
    kept.push(path[path.len() - 1].clone());
    let proven = proven_segments(checker, &kept, clearance)?;
    record_proven_lines(checker, &kept, &proven, clearance);
    let mut out = vec![kept[0].clone()];
    let mut repairs: Option<Search> = None;
    for (w, proven) in kept.windows(2).zip(proven) {
        if proven {
            out.push(w[1].clone());
            continue;
        }
        let done = repairs.as_ref().map_or(0, |r| r.iterations);
        let budget = opts.max_iterations.saturating_sub(done).max(1);
        let sub = rrt_connect(checker, rng, &w[0], &w[1], range, budget, out_of_time)?;
        let Some(sub_path) = sub.path else {
            return Ok(None);
        };
        let sub_path = shortcut(sub_path, checker, rng, opts.shortcut_rounds, out_of_time)?;
        out.extend(sub_path.into_iter().skip(1));
        let total = repairs.get_or_insert(Search { path: None, status: PlanStatus::Connected, iterations: 0, sizes: [0, 0] });
        total.iterations += sub.iterations;
        total.sizes = [total.sizes[0] + sub.sizes[0], total.sizes[1] + sub.sizes[1]];
    }
    Ok(Some(Proven { path: out, repairs }))
}

/// Records in the model's proven lines (`model::proven::ProvenLines`) the segments of `path`
/// that `proven_segments` certified at `clearance` (`proven`), each as it proved it, `a → a + Δ`
/// from the segment's first waypoint (`Δ` the short arc on continuous hinges), where both ends
/// lie inside the space's bounds: the planner's states are clamped into them, which a line
/// between two poses inside them leaves by rounding only (an ulp), so the motion proven is the
/// straight one `time_path` proves for that segment. (A repair's segments are not recorded:
/// its search proves some edges from their other end.)
fn record_proven_lines(checker: &Checker, path: &[Vec<f64>], proven: &[bool], clearance: f64) {
    let (model, space) = (checker.model, &checker.space);
    let inside = |q: &[f64]| q.iter().enumerate().all(|(j, x)| space.lo[j] <= *x && *x <= space.hi[j]);
    let mut delta = vec![0.0; model.njoint()];
    for (w, _) in path.windows(2).zip(proven).filter(|(_, &proven)| proven) {
        if inside(&w[0]) && inside(&w[1]) {
            space.delta(&w[0], &w[1], &mut delta);
            model.proven_lines.insert(&w[0], &delta, clearance);
        }
    }
}

/// Whether each segment of `path` is proven by the continuous certificate at `clearance`, the
/// segments certified in parallel on rayon's current pool, each worker taking the next segment
/// as it frees up (`threads::map_shared`: two to five segments of 20 µs to 2 ms each, which a
/// parallel iterator left on one thread), each decided alone (a motion forgets what its scratch
/// saw before), so the verdicts do not depend on the number of threads; an error is the first
/// in path order. (Cut
/// into halves, a direct move would keep two threads busy too, but the halves' verdicts are not
/// the whole segment's, which `certify_motions` of the returned path gives: a result that
/// contradicts itself.) The states placed count as checks.
fn proven_segments(checker: &mut Checker, path: &[Vec<f64>], clearance: f64) -> Result<Vec<bool>> {
    let (model, space) = (checker.model, &checker.space);
    let levers = Levers::of(model);
    // (the checker's buffers, where an edge it proved made them, to the first worker that
    // starts; the first set given back goes on to the repairs' edges)
    let home = Mutex::new(checker.motion.as_mut().and_then(|m| m.buffers.take()));
    let verdicts: Vec<Result<(bool, usize)>> = map_shared(
        path.len() - 1,
        2,
        || {
            let lent = home.lock().unwrap_or_else(PoisonError::into_inner).take();
            (Lent { buffers: Some(lent.unwrap_or_else(|| Spare::take(model))), home: &home }, vec![0.0; model.njoint()])
        },
        |(lent, delta), i| {
            let w = &path[i..i + 2];
            space.delta(&w[0], &w[1], delta);
            let ms = lent.buffers.as_mut().expect("lent until dropped");
            certified_edge(model, levers, space, &w[0], &w[1], delta, clearance, ms)
        },
    );
    if let Some(m) = checker.motion.as_mut() {
        m.buffers = home.into_inner().unwrap_or_else(PoisonError::into_inner);
    }
    let verdicts = verdicts.into_iter().collect::<Result<Vec<_>>>()?;
    checker.checks += verdicts.iter().map(|v| v.1 as u64).sum::<u64>();
    Ok(verdicts.into_iter().map(|v| v.0).collect())
}

/// Whether the motion `a → a + delta` (ending at `b`) is certified at `clearance`, and the states
/// it placed (`certify_motion`, from the middle first: `a` is free, and `edge_free` has refuted
/// cheaply at a few states, `b` among them, what it could); an error names the motion. The
/// continuous check of `Checker::edge_free` and of `proven_segments`.
#[allow(clippy::too_many_arguments)]
fn certified_edge(
    model: &RobotModel,
    levers: Levers,
    space: &Space,
    a: &[f64],
    b: &[f64],
    delta: &[f64],
    clearance: f64,
    ms: &mut MotionScratch,
) -> Result<(bool, usize)> {
    match certify_motion(model, levers, space, a, delta, clearance, Order::MiddleFirst, ms) {
        Ok(m) => Ok((m == Motion::Certified, ms.states)),
        Err(e) => Err(e.error(model, format!("planning motion {a:?} -> {b:?}"))),
    }
}

/// What one bidirectional search found.
struct Search {
    path: Option<Vec<Vec<f64>>>,
    status: PlanStatus,
    iterations: usize,
    sizes: [usize; 2],
}

/// RRT-Connect from `start` to `goal` with `checker`'s resolution, at most `max_iterations`
/// extensions or until `out_of_time`.
fn rrt_connect(
    checker: &mut Checker,
    rng: &mut ChaCha8Rng,
    start: &[f64],
    goal: &[f64],
    range: f64,
    max_iterations: usize,
    out_of_time: impl Fn() -> bool,
) -> Result<Search> {
    let k = start.len();
    let mut trees = [Tree::new(start), Tree::new(goal)];
    let mut target = vec![0.0; k];
    let mut joined: Option<(usize, usize)> = None; // (node in trees[0], node in trees[1])
    let mut status = PlanStatus::IterationLimit;
    let mut iterations = 0;
    while iterations < max_iterations {
        if out_of_time() {
            status = PlanStatus::TimeOut;
            break;
        }
        iterations += 1;
        let (a, b) = if iterations % 2 == 1 { (0, 1) } else { (1, 0) };
        sample(&checker.space, rng, &mut target);
        let new = match extend(&mut trees[a], checker, &target, range, &mut None)? {
            Extend::Trapped => continue,
            Extend::Advanced(i) | Extend::Reached(i) => i,
        };
        let q_new = trees[a].node(new).to_vec();
        // (the connect steps toward one target: each scans only the node the last one added)
        let mut known = None;
        loop {
            match extend(&mut trees[b], checker, &q_new, range, &mut known)? {
                Extend::Advanced(_) => continue,
                Extend::Trapped => break,
                Extend::Reached(j) => {
                    joined = Some(if a == 0 { (new, j) } else { (j, new) });
                    break;
                }
            }
        }
        if joined.is_some() {
            status = PlanStatus::Connected;
            break;
        }
    }
    let sizes = [trees[0].len(), trees[1].len()];
    let path = joined.map(|(i0, i1)| {
        let mut order: Vec<Vec<f64>> = trees[0].branch(i0).into_iter().rev().map(|i| trees[0].node(i).to_vec()).collect();
        // The joining node is in both trees (the same pose): skip its copy in the goal tree.
        order.extend(trees[1].branch(i1).into_iter().skip(1).map(|i| trees[1].node(i).to_vec()));
        order
    });
    Ok(Search { path, status, iterations, sizes })
}

/// Random shortcutting: join two waypoints directly when the segment between them is free.
///
/// A pair of waypoints found blocked is not tried again until the path changes (the same
/// segment, the same verdict), and shortcutting ends early once every pair has been tried: a
/// three-waypoint path whose one shortcut is blocked costs one check, not `rounds`.
fn shortcut(
    mut path: Vec<Vec<f64>>,
    checker: &mut Checker,
    rng: &mut ChaCha8Rng,
    rounds: usize,
    out_of_time: impl Fn() -> bool,
) -> Result<Vec<Vec<f64>>> {
    let mut blocked = std::collections::HashSet::new();
    for _ in 0..rounds {
        let m = path.len();
        if m < 3 || blocked.len() >= (m - 1) * (m - 2) / 2 || out_of_time() {
            break;
        }
        let i = rng.random_range(0..m - 2);
        let j = rng.random_range(i + 2..m);
        if blocked.contains(&(i, j)) {
            continue;
        }
        if checker.edge_free(&path[i], &path[j])? {
            path.drain(i + 1..j);
            blocked.clear();
        } else {
            blocked.insert((i, j));
        }
    }
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ModelDesc;

    #[test]
    fn check_order_visits_every_state_once_end_first() {
        for n in [1, 2, 3, 7, 64, 1000] {
            let o = check_order(n);
            assert_eq!(o[0], n);
            let mut s = o.clone();
            s.sort();
            assert_eq!(s, (1..=n).collect::<Vec<_>>());
        }
    }

    #[test]
    fn pendulum_swings_the_short_way_without_hitting_the_floor() {
        let model = RobotModel::new(ModelDesc::example_pendulum()).unwrap();
        let opts = PlanOptions::default();
        let r = plan_path(&model, &[0.3], &[-0.3], &opts).unwrap();
        assert!(r.found());
        let p = &r.path;
        assert!((p[0] - 0.3).abs() < 1e-12 && (p[p.len() - 1] + 0.3).abs() < 1e-12);
    }

    /// Issue 19: `joints/interpolate.rs` and this file wrapped differently at ±π. A continuous
    /// pendulum (free at every angle) planned between ±π, 0 and the float just below -π: the
    /// direct edge's checked states are the wrapped states of `interpolate_so2` between the same
    /// waypoints, bit for bit, and a half turn moves the negative way in both.
    #[test]
    fn planned_edges_replay_through_interpolate_at_a_half_turn() {
        use std::f64::consts::PI;

        use crate::joints::interpolate::interpolate_so2;

        let mut desc = ModelDesc::example_pendulum();
        desc.jnt_limited = vec![false];
        let model = RobotModel::new(desc).unwrap();
        let below = f64::from_bits((-PI).to_bits() + 1);
        let space = Space { lo: vec![-PI], hi: vec![PI], wraps: vec![true], couplings: Default::default() };
        let opts = PlanOptions { resolution: 0.1, ..PlanOptions::default() };
        for (s, g) in [(PI, 0.0), (-PI, 0.0), (0.0, PI), (0.0, -PI), (PI, -PI), (below, 0.0), (0.0, below), (3.0 * PI, 1.0)] {
            let r = plan_path(&model, &[s], &[g], &opts).unwrap();
            assert_eq!(r.status, PlanStatus::Direct, "{s} -> {g}");
            assert_eq!(r.path, vec![wrap(s), wrap(g)], "{s} -> {g}");
            let (a, b) = (&r.path[0..1], &r.path[1..2]);
            let mut d = [0.0];
            space.delta(a, b, &mut d);
            assert!(d[0] < PI && d[0] >= -PI);
            let n = ((d[0].abs() / opts.resolution).ceil() as usize).max(1);
            let replay = interpolate_so2(a, b, n + 1, &[true]).unwrap();
            for (i, x) in replay.iter().enumerate().take(n) {
                let mut q = [0.0];
                space.along(a, &d, i as f64 / n as f64, &mut q);
                assert_eq!(q[0].to_bits(), wrap(*x).to_bits(), "{s} -> {g}, state {i}");
            }
            assert!((wrap(replay[n]) - b[0]).abs() < 1e-15 || (wrap(replay[n]) - b[0]).abs() > 2.0 * PI - 1e-15);
            if (b[0] - a[0]).abs() == PI {
                assert!(d[0] == -PI && replay[1] < replay[0], "a half turn moves the negative way: {s} -> {g}");
            }
        }
    }

    /// `Tree::nearest` against the planner's metric taken the plain way, `sqrt` of `Space::squared`
    /// to every node and the first of the least kept: random trees on spaces with and without
    /// wrapping joints, with repeated nodes (ties) and targets on a node, scanned whole and
    /// continued from a scan of fewer nodes (`known`, as RRT-Connect's connect steps do).
    #[test]
    fn nearest_is_the_first_least_distance_scanned_whole_or_continued() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for wraps in [vec![false; 9], vec![true, false, true, false, false, false, true, false, false]] {
            let space = Space { lo: vec![-3.0; 9], hi: vec![3.0; 9], wraps, couplings: Default::default() };
            for round in 0..200 {
                let mut q = vec![0.0; 9];
                sample(&space, &mut rng, &mut q);
                let mut tree = Tree::new(&q);
                let n = 1 + round % 40;
                for i in 1..n {
                    // (a repeat of an earlier node now and then: equal distances)
                    if rng.random_range(0..4) == 0 {
                        q = tree.node(rng.random_range(0..i)).to_vec();
                    } else {
                        sample(&space, &mut rng, &mut q);
                    }
                    tree.push(&q, 0);
                }
                let mut target = vec![0.0; 9];
                if round % 5 == 0 {
                    target.copy_from_slice(tree.node(round % n));
                } else {
                    sample(&space, &mut rng, &mut target);
                }
                let plain = |upto: usize| {
                    let mut best = (f64::INFINITY, 0);
                    for i in 0..upto {
                        let d = space.squared(tree.node(i), &target).sqrt();
                        if d < best.0 {
                            best = (d, i);
                        }
                    }
                    best
                };
                let whole = tree.nearest(&space, &target, None);
                assert_eq!((whole.dist, whole.node), plain(n), "round {round}");
                assert_eq!(whole.seen, n);
                // continued: the scan of the first `m` nodes, then the rest
                let m = 1 + round % n;
                let mut part = tree.clone();
                part.nodes.truncate(m * 9);
                part.parent.truncate(m);
                let first = part.nearest(&space, &target, None);
                assert_eq!((first.dist, first.node), plain(m), "round {round}");
                let on = tree.nearest(&space, &target, Some(first));
                assert_eq!((on.dist, on.node, on.seen), (whole.dist, whole.node, n), "round {round}");
            }
        }
    }

    #[test]
    fn bad_arguments_are_errors() {
        let model = RobotModel::new(ModelDesc::example_pendulum()).unwrap();
        let o = PlanOptions { max_time: 0.0, ..PlanOptions::default() };
        assert!(plan_path(&model, &[0.0], &[0.1], &o).is_err());
        assert!(plan_path(&model, &[0.0, 1.0], &[0.1], &PlanOptions::default()).is_err());
        assert!(plan_path(&model, &[f64::NAN], &[0.1], &PlanOptions::default()).is_err());
        let o = PlanOptions { resolution: 0.0, ..PlanOptions::default() };
        assert!(plan_path(&model, &[0.0], &[0.1], &o).is_err());
    }
}
