//! Inverse kinematics: joint poses whose frame (a body, or a site or geom fixed to one) reaches a
//! target pose, certified collision-free by the exact labeller.
//!
//! **The solve.** Levenberg–Marquardt on the SE(3) error of the frame, per seed:
//!
//! ```text
//! e = [p* − p(q);  log(R* Rᵀ(q))]            (world frame; metres, radians)
//! J = [ω_j × (p − a_j); ω_j]  (hinge j),  [ω_j; 0]  (slide j)    (closed form, world frame)
//! (JᵀWJ + λ·(diag JᵀWJ + ε)) Δv = JᵀW e,     W = diag(1, 1, 1, L², L², L²)
//! ```
//!
//! over the variables `v`: the joints that move the frame, less the dependent joints of joint
//! couplings (`joints/couplings.rs`), which follow their independent ones (the Jacobian's columns are
//! combined by the chain rule, `dq/dv`) and scene joints (a family's layout stays put). Every
//! iterate is clamped into the joint limits, continuous hinges wrapped, dependent joints
//! recomputed: every pose tried is one the robot can take. λ adapts (÷3 on a step that lowers
//! ‖e‖_W, ×4 and retry otherwise). Position-only targets drop the rotation rows.
//!
//! **Seeds and the answer.** Seed 0 is the start (clamped, coupled); seeds 1–3 perturb it; the rest
//! are uniform within the limits, from ChaCha8 seeded with `seed` on the target's own stream (the
//! answer does not depend on the thread count). A seed *reaches* the target within the tolerances;
//! the pose it reached is then certified free (`fastpath::certified_pose`: no contact, every pair
//! more than the clearance apart, and `RobotModel::feasible`). The answer is the certified pose
//! nearest the start among the near seeds (0–3) when one of them certifies, else the first
//! certified one of the uniform seeds. A seed that reaches the target in contact (or within the
//! clearance) first tries to move out: LM on the target's error stacked with a row per pair
//! nearer than 5 mm beyond its margin, `nᵀ(J₂ − J₁) Δv = 5 mm + margin − d` (the pair's
//! distance linearised at its nearest points, parry's contact query: how mink and dm_robotics
//! constrain collisions), so that the redundancy the target leaves takes the robot out of
//! contact; the pose it ends in is certified like any other, never on the rows' word. Nothing is certified as reaching a target it does not reach
//! (within tolerance) or in a pose that collides: such targets come back with their best pose,
//! error and reason.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::collision::collide::{first_error, pair_witness, Scratch};
use crate::collision::fastpath::certified_pose;
use crate::error::{invalid_input, Error, Result};
use crate::joints::angles::wrap;
use crate::model::broad::check_clearance;
use crate::model::RobotModel;

/// One target of a frame: a position (metres, world), and a rotation unless position-only.
#[derive(Clone, Copy, Debug)]
pub struct IkTarget {
    pub pos: [f64; 3],
    pub rot: Option<UnitQuaternion<f64>>,
}

/// Settings of one batch.
#[derive(Clone, Debug)]
pub struct IkOptions {
    /// The frame's body and its pose in that body's frame (identity for the body itself).
    pub body: usize,
    pub local: Isometry3<f64>,
    /// Seeds tried per target, at most.
    pub seeds: usize,
    /// LM iterations per seed, at most.
    pub iterations: usize,
    /// A seed iterates until its position error ≤ `tol_pos` metres and rotation error ≤
    /// `tol_rot` radians (the solver's own target, tighter than the acceptance).
    pub tol_pos: f64,
    pub tol_rot: f64,
    /// Reached: position error ≤ `accept_pos` metres and rotation error ≤ `accept_rot` radians
    /// (the caller's tolerances). A seed that stalls between `tol_*` and `accept_*` reaches the
    /// target, so that the outcome never contradicts the errors it reports.
    pub accept_pos: f64,
    pub accept_rot: f64,
    /// An axis of the frame (unit, in the frame's own coordinates) left free: the target's
    /// rotation then fixes only where that axis points (a symmetric part grasped at any angle
    /// about it, a 5-DoF arm's approach axis); the rotation error is the angle between the
    /// frame's axis and the target's.
    pub free_axis: Option<Vector3<f64>>,
    /// The certificate's clearance (metres).
    pub clearance: f64,
    pub seed: u64,
    /// Whether a seed that reaches the target in contact tries the distance rows (`escape`).
    pub escape: bool,
    /// Joints that are variables although they do not move the frame (a gripper's jaw asked to
    /// move): their Jacobian columns are zero, so they move only where the escape rows or a
    /// uniform seed take them. Empty: none (the rest keep their start values).
    pub moving: Vec<bool>,
    /// A posture (K,) the answers should be near: each seed that reaches the target then moves
    /// in the target's null space towards it (`toward_posture`), and the certified answer
    /// nearest it is chosen. None: the start plays that part (no null-space motion).
    pub posture: Option<Vec<f64>>,
}

impl IkOptions {
    pub fn new(body: usize, local: Isometry3<f64>) -> Self {
        IkOptions {
            body,
            local,
            seeds: 128,
            iterations: 60,
            tol_pos: 1e-6,
            tol_rot: 1e-6,
            accept_pos: 1e-6,
            accept_rot: 1e-6,
            free_axis: None,
            clearance: 1e-6,
            seed: 0,
            escape: true,
            moving: Vec::new(),
            posture: None,
        }
    }
}

/// Why a target's answer is what it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IkOutcome {
    /// Reached and certified free.
    Certified,
    /// No seed came within the tolerances; the pose with the smallest error is returned.
    Unreachable,
    /// Seeds reached the target, but only in poses that collide or come within the clearance.
    Colliding,
}

/// One target's answer.
#[derive(Clone, Debug)]
pub struct IkAnswer {
    pub pose: Vec<f64>,
    pub outcome: IkOutcome,
    pub reached: bool,
    pub pos_err: f64,
    pub rot_err: f64,
    /// LM iterations over every seed tried, and the seeds tried.
    pub iterations: usize,
    pub seeds: usize,
}

/// Seeds near the start (the start and its perturbations), tried before the uniform ones.
const NEAR_SEEDS: usize = 4;
/// Standard deviation (radians / metres) of the perturbed seeds.
const PERTURB: f64 = 0.3;
/// Characteristic length weighing radians against metres (`W`).
const LENGTH: f64 = 0.3;
/// Targets per parallel work item (fixed: the split never depends on the thread count).
const CHUNK: usize = 8;

/// The kinematic structure one batch needs: which joints move the frame, and how.
struct Chain {
    /// Variable joints (independent, not scene joints, moving the frame).
    vars: Vec<usize>,
    /// `dq/dv`, `(K, nv)` row-major, at the current pose (dependent rows from the couplings).
    dq: Vec<f64>,
}

/// Per-thread scratch: frames, joint axes and anchors, the labeller's scratch.
struct Work {
    frames: Vec<Isometry3<f64>>,
    axes: Vec<Vector3<f64>>,
    anchors: Vec<Vector3<f64>>,
    scratch: Scratch,
    q: Vec<f64>,
    trial: Vec<f64>,
}

/// FK of `w.q` that also records each joint's world axis and anchor (the hinge's fixed point),
/// as `kinematics::body_poses` places the bodies.
fn place(model: &RobotModel, w: &mut Work) {
    let q = &w.q;
    w.frames[0] = Isometry3::identity();
    for b in 1..model.body_parent.len() {
        let mut x = w.frames[model.body_parent[b]] * model.body_local[b];
        let (j0, j1) = model.body_joints[b];
        for (j, (jnt, &qj)) in model.joints[j0..j1].iter().zip(&q[j0..j1]).enumerate().map(|(i, p)| (j0 + i, p)) {
            let angle = qj - jnt.qpos0;
            let axis = x.rotation * jnt.axis.into_inner();
            if jnt.hinge {
                let anchor = (x * Point3::from(jnt.anchor)).coords;
                let mut rot = x.rotation * crate::model::kinematics::axis_rotation(jnt.axis.into_inner(), angle);
                rot.renormalize_fast();
                x.translation.vector = anchor - rot * jnt.anchor;
                x.rotation = rot;
                w.anchors[j] = anchor;
            } else {
                w.anchors[j] = x.translation.vector;
                x.translation.vector += axis * angle;
            }
            w.axes[j] = axis;
        }
        w.frames[b] = x;
    }
}

/// The weighted error `e` (6 or 3 rows) of the frame in the placed state, and its two norms.
fn error(opts: &IkOptions, target: &IkTarget, w: &Work, e: &mut [f64; 6]) -> (f64, f64) {
    let frame = w.frames[opts.body] * opts.local;
    let dp = Vector3::from(target.pos) - frame.translation.vector;
    e[..3].copy_from_slice(dp.as_slice());
    let mut rot_err = 0.0;
    if let Some(r) = target.rot {
        let v = match opts.free_axis {
            None => (r * frame.rotation.inverse()).scaled_axis(),
            Some(a) => swing(&(frame.rotation * a), &(r * a)),
        };
        e[3..].copy_from_slice(v.as_slice());
        rot_err = v.norm();
    }
    (dp.norm(), rot_err)
}

/// The rotation vector (axis × angle, radians) of the shortest rotation taking unit vector `u`
/// onto unit vector `t`: perpendicular to both, so it has no part about `t`.
fn swing(u: &Vector3<f64>, t: &Vector3<f64>) -> Vector3<f64> {
    let c = u.cross(t);
    let (s, d) = (c.norm(), u.dot(t));
    if s > 1e-15 {
        return c * (s.atan2(d) / s);
    }
    if d > 0.0 {
        return Vector3::zeros();
    }
    // opposite: half a turn about any axis perpendicular to u
    let other = if u.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    u.cross(&other).normalize() * std::f64::consts::PI
}

/// The frame's Jacobian rows (`rows`: 3, position; 6, and rotation) over every joint, with a free
/// axis's rotation about the target's axis taken out of the rotation rows (`(I − t tᵀ) J_ω`):
/// turning about it costs nothing.
fn frame_jacobian(model: &RobotModel, w: &Work, opts: &IkOptions, target: &IkTarget, rows: usize, jac: &mut DMatrix<f64>) {
    let p = (w.frames[opts.body] * opts.local).translation.vector;
    point_jacobian(model, w, opts.body, &p, rows, jac);
    if let (Some(a), Some(r), 6) = (opts.free_axis, target.rot, rows) {
        let t = r * a;
        let proj = Matrix3::identity() - t * t.transpose();
        for c in 0..jac.ncols() {
            let col = proj * Vector3::new(jac[(3, c)], jac[(4, c)], jac[(5, c)]);
            (jac[(3, c)], jac[(4, c)], jac[(5, c)]) = (col.x, col.y, col.z);
        }
    }
}

/// `‖e‖_W²`.
fn cost(e: &[f64; 6], rows: usize) -> f64 {
    let p = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
    if rows == 3 {
        p
    } else {
        p + LENGTH * LENGTH * (e[3] * e[3] + e[4] * e[4] + e[5] * e[5])
    }
}

impl Chain {
    fn of(model: &RobotModel, body: usize, scene: &[bool], moving: &[bool]) -> Chain {
        let k = model.njoint();
        let mut moves: Vec<bool> = (0..k).map(|j| moving.get(j).copied().unwrap_or(false)).collect();
        let mut b = body;
        while b != 0 {
            let (j0, j1) = model.body_joints[b];
            moves[j0..j1].iter_mut().for_each(|m| *m = true);
            b = model.body_parent[b];
        }
        let dependent: Vec<usize> = model.couplings.rows().iter().map(|c| c.dep as usize).collect();
        // a joint moves the frame also through the dependents that follow it
        for c in model.couplings.rows().iter().rev() {
            if c.indep >= 0 && moves[c.dep as usize] {
                moves[c.indep as usize] = true;
            }
        }
        let vars: Vec<usize> = (0..k).filter(|&j| moves[j] && !dependent.contains(&j) && !scene.get(j).copied().unwrap_or(false)).collect();
        Chain { dq: vec![0.0; k * vars.len()], vars }
    }

    /// `dq/dv` at pose `q`: identity on the variables, the couplings' slopes down their rows.
    fn update(&mut self, model: &RobotModel, q: &[f64]) {
        let nv = self.vars.len();
        self.dq.iter_mut().for_each(|v| *v = 0.0);
        for (i, &j) in self.vars.iter().enumerate() {
            self.dq[j * nv + i] = 1.0;
        }
        for c in model.couplings.rows() {
            if c.indep < 0 {
                continue;
            }
            let (d, x) = (c.dep as usize, c.indep as usize);
            let s = c.slope(q[x]);
            for i in 0..nv {
                self.dq[d * nv + i] = s * self.dq[x * nv + i];
            }
        }
    }
}

/// Moves `q` by `Δv` on the variables into `out`: limited joints clamped, continuous hinges
/// wrapped, dependent joints recomputed.
fn step(model: &RobotModel, chain: &Chain, q: &[f64], dv: &DVector<f64>, out: &mut [f64]) {
    out.copy_from_slice(q);
    for (i, &j) in chain.vars.iter().enumerate() {
        let v = q[j] + dv[i];
        out[j] = if model.limited[j] {
            v.clamp(model.limits[j][0], model.limits[j][1])
        } else if model.joints[j].hinge {
            wrap(v)
        } else {
            v
        };
    }
    model.couplings.apply(out);
}

/// LM from the seed in `w.q` (updated in place); returns (reached, position error, rotation
/// error, iterations).
fn solve(model: &RobotModel, chain: &mut Chain, opts: &IkOptions, target: &IkTarget, w: &mut Work) -> (bool, f64, f64, usize) {
    let rows = if target.rot.is_some() { 6 } else { 3 };
    let nv = chain.vars.len();
    let mut e = [0.0; 6];
    place(model, w);
    let (mut pe, mut re) = error(opts, target, w, &mut e);
    let mut c = cost(&e, rows);
    let mut lambda = 1e-3;
    let weight = |r: usize| if r < 3 { 1.0 } else { LENGTH * LENGTH };
    let mut iters = 0;
    let mut jac = DMatrix::<f64>::zeros(rows, model.njoint());
    while iters < opts.iterations {
        if pe <= opts.tol_pos && re <= opts.tol_rot {
            return (true, pe, re, iters);
        }
        iters += 1;
        // the geometric Jacobian of the frame point over every joint that moves it, then dq/dv
        frame_jacobian(model, w, opts, target, rows, &mut jac);
        chain.update(model, &w.q);
        let dq = DMatrix::from_row_slice(model.njoint(), nv, &chain.dq);
        let jv = &jac * dq; // (rows, nv)
        let mut a = DMatrix::<f64>::zeros(nv, nv);
        let mut g = DVector::<f64>::zeros(nv);
        for r in 0..rows {
            let wr = weight(r);
            for i in 0..nv {
                g[i] += wr * jv[(r, i)] * e[r];
                for k in 0..nv {
                    a[(i, k)] += wr * jv[(r, i)] * jv[(r, k)];
                }
            }
        }
        let mut improved = false;
        for _ in 0..12 {
            let mut m = a.clone();
            for i in 0..nv {
                m[(i, i)] += lambda * (a[(i, i)] + 1e-9);
            }
            let Some(dv) = m.cholesky().map(|ch| ch.solve(&g)) else {
                lambda *= 4.0;
                continue;
            };
            step(model, chain, &w.q, &dv, &mut w.trial);
            std::mem::swap(&mut w.q, &mut w.trial);
            place(model, w);
            let mut e2 = [0.0; 6];
            let (pe2, re2) = error(opts, target, w, &mut e2);
            let c2 = cost(&e2, rows);
            if c2 < c {
                (e, pe, re, c) = (e2, pe2, re2, c2);
                lambda = (lambda / 3.0).max(1e-12);
                improved = true;
                break;
            }
            std::mem::swap(&mut w.q, &mut w.trial); // back to the iterate
            lambda *= 4.0;
        }
        if !improved {
            place(model, w);
            break; // a local minimum (or a limit) this seed cannot leave
        }
    }
    (pe <= opts.tol_pos && re <= opts.tol_rot, pe, re, iters)
}

/// Null-space steps towards the posture, at most.
const POSTURE_ITERATIONS: usize = 30;

/// From a pose in `w.q` that reaches the target: steps towards `posture` within the target's
/// null space, `Δv = ½·(I − J⁺J)·(v_posture − v)` (the task-priority rule: the target first, the
/// posture with what it leaves; mink's posture task, solved here as a secondary one), each
/// followed by Levenberg–Marquardt back onto the target (the null space is first-order); a step
/// is kept only while it stays within the tolerances and comes nearer the posture. A target
/// that fixes every joint (a full pose for a 6-joint arm) leaves no null space and no step.
/// Returns the LM iterations.
fn toward_posture(model: &RobotModel, chain: &mut Chain, opts: &IkOptions, target: &IkTarget, w: &mut Work, posture: &[f64]) -> usize {
    let rows = if target.rot.is_some() { 6 } else { 3 };
    let (nv, k) = (chain.vars.len(), model.njoint());
    let mut jac = DMatrix::<f64>::zeros(rows, k);
    let mut iters = 0;
    for _ in 0..POSTURE_ITERATIONS {
        place(model, w);
        frame_jacobian(model, w, opts, target, rows, &mut jac);
        chain.update(model, &w.q);
        let dq = DMatrix::from_row_slice(k, nv, &chain.dq);
        let mut jv = &jac * dq;
        for r in 3..rows {
            jv.row_mut(r).scale_mut(LENGTH);
        }
        let pull = DVector::from_iterator(
            nv,
            chain.vars.iter().map(|&j| {
                let d = posture[j] - w.q[j];
                if model.joints[j].hinge && !model.limited[j] {
                    wrap(d)
                } else {
                    d
                }
            }),
        );
        let Ok(pinv) = jv.clone().pseudo_inverse(1e-9) else { break };
        let dv = (DMatrix::<f64>::identity(nv, nv) - pinv * jv) * pull * 0.5;
        let size = dv.norm();
        if size.is_nan() || size <= 1e-9 {
            break;
        }
        let keep = w.q.clone();
        let before = distance(model, posture, &w.q);
        step(model, chain, &keep, &dv, &mut w.q);
        let (_, pe, re, it) = solve(model, chain, opts, target, w);
        iters += it;
        if !(pe <= opts.accept_pos && re <= opts.accept_rot && distance(model, posture, &w.q) < before - 1e-12) {
            w.q.copy_from_slice(&keep);
            break;
        }
    }
    place(model, w);
    iters
}

/// Distance (metres, beyond each pair's margin) the escape rows push pairs apart to.
const SAFE: f64 = 0.005;
/// Pairs closer than this (metres) are measured for the rows.
const ACTIVE: f64 = 0.02;
/// Escape iterations at most.
const ESCAPE_ITERATIONS: usize = 30;

/// From a pose in `w.q` that reaches the target but is not certified: Levenberg–Marquardt on the
/// target's error stacked with one row per pair nearer than `SAFE` beyond its margin, `nᵀ(J₂ −
/// J₁) Δv = SAFE + margin − d` (the pair's distance, linearised at its nearest points, as mink and
/// dm_robotics constrain it), so that the redundancy the target leaves moves the robot out of
/// contact; then the target alone again. Returns the LM iterations; the caller certifies.
fn escape(model: &RobotModel, chain: &mut Chain, opts: &IkOptions, target: &IkTarget, w: &mut Work) -> Result<usize> {
    let rows_t = if target.rot.is_some() { 6 } else { 3 };
    let nv = chain.vars.len();
    let k = model.njoint();
    let mut jac = DMatrix::<f64>::zeros(rows_t, k);
    let (mut j1, mut j2) = (DMatrix::<f64>::zeros(3, k), DMatrix::<f64>::zeros(3, k));
    let mut iters = 0;
    let (mut last, mut stalled) = (f64::INFINITY, 0);
    for _ in 0..ESCAPE_ITERATIONS {
        place(model, w);
        w.scratch.place(model, &w.q, true);
        let mut rows: Vec<(DVector<f64>, f64)> = Vec::new(); // (row over the K joints, wanted Δd)
        for (p, pair) in model.pairs.iter().enumerate() {
            let (gap, _) = model.broad.sphere_gap(&w.scratch.broad, p, &model.geoms);
            let need = SAFE + pair.margin.max(opts.clearance);
            if gap > ACTIVE.max(need) {
                continue;
            }
            let Some((d, p1, p2, n)) = pair_witness(model, &w.scratch, p, ACTIVE.max(need)).map_err(|e| e.error(model, "an IK pose"))?
            else {
                continue;
            };
            if d >= need {
                continue;
            }
            point_jacobian(model, w, model.geoms[pair.g1].body, &p1.coords, 3, &mut j1);
            point_jacobian(model, w, model.geoms[pair.g2].body, &p2.coords, 3, &mut j2);
            let row = (&j2 - &j1).transpose() * n; // (K,)
            rows.push((row, need - d));
        }
        if rows.is_empty() {
            break;
        }
        // no redundancy left to use (a full pose on a 6-joint arm): stop after two steps that
        // take less than a tenth off the total depth of the pairs still too near
        let depth: f64 = rows.iter().map(|(_, want)| want).sum();
        stalled = if depth > 0.9 * last { stalled + 1 } else { 0 };
        if stalled >= 2 {
            break;
        }
        last = depth;
        iters += 1;
        let mut e = [0.0; 6];
        error(opts, target, w, &mut e);
        frame_jacobian(model, w, opts, target, rows_t, &mut jac);
        chain.update(model, &w.q);
        let dq = DMatrix::from_row_slice(k, nv, &chain.dq);
        let jv = &jac * &dq;
        let mut a = DMatrix::<f64>::zeros(nv, nv);
        let mut g = DVector::<f64>::zeros(nv);
        for (r, &er) in e.iter().enumerate().take(rows_t) {
            let wr = if r < 3 { 1.0 } else { LENGTH * LENGTH };
            let jr = jv.row(r).transpose();
            a += wr * &jr * jr.transpose();
            g += wr * er * &jr;
        }
        for (row, want) in &rows {
            let jr = dq.transpose() * row;
            a += &jr * jr.transpose();
            g += *want * &jr;
        }
        for i in 0..nv {
            a[(i, i)] += 1e-3 * (a[(i, i)] + 1e-9);
        }
        let Some(dv) = a.cholesky().map(|ch| ch.solve(&g)) else {
            break;
        };
        step(model, chain, &w.q, &dv, &mut w.trial);
        std::mem::swap(&mut w.q, &mut w.trial);
    }
    let (_, _, _, it) = solve(model, chain, opts, target, w);
    Ok(iters + it)
}

/// The geometric Jacobian (`rows` × K: linear velocity, then, with 6 rows, angular) of the
/// world point `p` carried by body `body`: `ω_j × (p − a_j)` and `ω_j` per hinge, `ω_j` and 0 per
/// slide, for the joints on the body's chain; 0 elsewhere.
fn point_jacobian(model: &RobotModel, w: &Work, body: usize, p: &Vector3<f64>, rows: usize, jac: &mut DMatrix<f64>) {
    jac.fill(0.0);
    let mut b = body;
    while b != 0 {
        let (j0, j1) = model.body_joints[b];
        for j in j0..j1 {
            let a = w.axes[j];
            let hinge = model.joints[j].hinge;
            let lin = if hinge { a.cross(&(p - w.anchors[j])) } else { a };
            for r in 0..3 {
                jac[(r, j)] = lin[r];
                if rows == 6 && hinge {
                    jac[(3 + r, j)] = a[r];
                }
            }
        }
        b = model.body_parent[b];
    }
}

/// Joint-space distance from `a` to `b`, continuous hinges the short way.
fn distance(model: &RobotModel, a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .enumerate()
        .map(|(j, (x, y))| {
            let d = if model.joints[j].hinge && !model.limited[j] { wrap(y - x) } else { y - x };
            d * d
        })
        .sum::<f64>()
        .sqrt()
}

/// Solves each target (`starts`: `(N, K)` row-major, the start of each; `scene`: per joint,
/// whether it is a scene joint, kept at its start value). In parallel on rayon's current pool;
/// the answers do not depend on the number of threads.
pub fn ik(model: &RobotModel, targets: &[IkTarget], starts: &[f64], scene: &[bool], opts: &IkOptions) -> Result<Vec<IkAnswer>> {
    let k = model.njoint();
    let n = targets.len();
    if starts.len() != n * k {
        return invalid_input(format!("starts must have shape ({n}, {k}); got {} values", starts.len()));
    }
    if opts.body == 0 || opts.body >= model.nbody() {
        return invalid_input(format!("the frame's body {} is not a body of the robot (1..{})", opts.body, model.nbody()));
    }
    if opts.seeds == 0 {
        return invalid_input("seeds must be at least 1");
    }
    if !(opts.tol_pos > 0.0 && opts.tol_rot > 0.0) {
        return invalid_input("tolerances must be positive");
    }
    check_clearance(opts.clearance)?;
    if let Some(i) = starts.iter().position(|v| !v.is_finite()) {
        return invalid_input(format!("start {} joint {} is not finite", i / k, i % k));
    }
    let ranges = model.sampling_ranges()?;
    let chain = Chain::of(model, opts.body, scene, &opts.moving);
    if chain.vars.is_empty() {
        return invalid_input("no joint moves the frame: nothing to solve for");
    }
    let idx: Vec<usize> = (0..n).collect();
    let parts: Vec<Result<Vec<IkAnswer>>> = idx
        .par_chunks(CHUNK)
        .map_init(
            || {
                let w = Work {
                    frames: vec![Isometry3::identity(); model.nbody()],
                    axes: vec![Vector3::zeros(); k],
                    anchors: vec![Vector3::zeros(); k],
                    scratch: Scratch::new(model),
                    q: vec![0.0; k],
                    trial: vec![0.0; k],
                };
                (w, Chain { vars: chain.vars.clone(), dq: chain.dq.clone() })
            },
            |(w, chain), items| {
                items
                    .iter()
                    .map(|&i| {
                        crate::cancel::check()?;
                        one(model, chain, opts, &ranges, &targets[i], &starts[i * k..(i + 1) * k], i, w)
                    })
                    .collect()
            },
        )
        .collect();
    Ok(first_error(parts)?.concat())
}

/// The seeds of target `index`, in order, and the answer (module docs).
#[allow(clippy::too_many_arguments)]
fn one(
    model: &RobotModel,
    chain: &mut Chain,
    opts: &IkOptions,
    ranges: &[[f64; 2]],
    target: &IkTarget,
    start: &[f64],
    index: usize,
    w: &mut Work,
) -> Result<IkAnswer> {
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    rng.set_stream(index as u64);
    let mut home = start.to_vec();
    for ((h, &[lo, hi]), &limited) in home.iter_mut().zip(&model.limits).zip(&model.limited) {
        if limited {
            *h = h.clamp(lo, hi);
        }
    }
    model.couplings.apply(&mut home);
    let mut best_certified: Option<(f64, Vec<f64>, f64, f64)> = None;
    let mut best_any: Option<(f64, Vec<f64>, f64, f64, bool)> = None; // (cost, pose, pe, re, reached)
    let (mut iterations, mut tried) = (0usize, 0usize);
    for s in 0..opts.seeds {
        if s == NEAR_SEEDS && best_certified.is_some() {
            break; // a near seed certified: the nearest of them is the answer
        }
        if s > NEAR_SEEDS && best_certified.is_some() {
            break; // the first certified uniform seed
        }
        w.q.copy_from_slice(&home);
        if s > 0 {
            for &j in &chain.vars {
                let [lo, hi] = ranges[j];
                let v = if s < NEAR_SEEDS {
                    // a normal draw (Box–Muller) around the start
                    let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random::<f64>());
                    home[j] + PERTURB * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
                } else {
                    lo + (hi - lo) * rng.random::<f64>()
                };
                w.q[j] = if model.limited[j] { v.clamp(lo, hi) } else { wrap(v) };
            }
            model.couplings.apply(&mut w.q);
        }
        tried += 1;
        let (converged, pe, re, it) = solve(model, chain, opts, target, w);
        let reached = converged || (pe <= opts.accept_pos && re <= opts.accept_rot);
        iterations += it;
        let (pe, re) = match &opts.posture {
            Some(posture) if reached => {
                iterations += toward_posture(model, chain, opts, target, w, posture);
                let mut e = [0.0; 6];
                error(opts, target, w, &mut e)
            }
            _ => (pe, re),
        };
        let c = pe * pe + LENGTH * LENGTH * re * re;
        if reached {
            let certify = |w: &mut Work| -> Result<bool> {
                Ok(model.feasible(&w.q)
                    && certified_pose(model, &w.q, opts.clearance, &mut w.scratch)
                        .map_err(|e| e.error(model, format!("target {index}")))?)
            };
            let mut free = certify(w)?;
            let (mut pe, mut re) = (pe, re);
            if !free && opts.escape {
                // in contact, or within the clearance: the distance rows move it out, if they can
                let keep = w.q.clone();
                iterations += escape(model, chain, opts, target, w)?;
                place(model, w);
                let mut e = [0.0; 6];
                let (pe2, re2) = error(opts, target, w, &mut e);
                if pe2 <= opts.accept_pos && re2 <= opts.accept_rot && certify(w)? {
                    (free, pe, re) = (true, pe2, re2);
                } else {
                    w.q.copy_from_slice(&keep);
                }
            }
            if free {
                let d = distance(model, opts.posture.as_deref().unwrap_or(&home), &w.q);
                if best_certified.as_ref().is_none_or(|(bd, ..)| d < *bd) {
                    best_certified = Some((d, w.q.clone(), pe, re));
                }
                continue;
            }
        }
        let better = match &best_any {
            None => true,
            Some((bc, _, _, _, br)) => (reached && !br) || (reached == *br && c < *bc),
        };
        if better {
            best_any = Some((c, w.q.clone(), pe, re, reached));
        }
    }
    Ok(match (best_certified, best_any) {
        (Some((_, pose, pe, re)), _) => {
            IkAnswer { pose, outcome: IkOutcome::Certified, reached: true, pos_err: pe, rot_err: re, iterations, seeds: tried }
        }
        (None, Some((_, pose, pe, re, reached))) => IkAnswer {
            pose,
            outcome: if reached { IkOutcome::Colliding } else { IkOutcome::Unreachable },
            reached,
            pos_err: pe,
            rot_err: re,
            iterations,
            seeds: tried,
        },
        (None, None) => return Err(Error::InvalidInput(format!("target {index}: no seed was tried"))),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planning::motion::tests::arm;

    /// `planning/motion.rs`'s arm (skew hinges with off-origin anchors, a body with a hinge then a slide,
    /// a floor and a box): targets made by FK of certified free poses are reached and certified,
    /// an out-of-reach one is reported, and answers do not depend on threads.
    #[test]
    fn fk_targets_are_reached_certified_and_thread_independent() {
        let model = arm();
        let k = model.njoint();
        let mut w = Work {
            frames: vec![Isometry3::identity(); model.nbody()],
            axes: vec![Vector3::zeros(); k],
            anchors: vec![Vector3::zeros(); k],
            scratch: Scratch::new(&model),
            q: vec![0.0; k],
            trial: vec![0.0; k],
        };
        let poses = crate::joints::sample::sample_uniform(&model.sampling_ranges().unwrap(), 200, 3).unwrap();
        let mut targets = Vec::new();
        for q in poses.chunks_exact(k) {
            if targets.len() == 4 || !certified_pose(&model, q, 1e-6, &mut w.scratch).unwrap() {
                continue;
            }
            w.q.copy_from_slice(q);
            place(&model, &mut w);
            let f = w.frames[3];
            targets.push(IkTarget { pos: f.translation.vector.into(), rot: (targets.len() != 1).then_some(f.rotation) });
        }
        assert_eq!(targets.len(), 4);
        targets.push(IkTarget { pos: [2.0, 0.0, 0.3], rot: None }); // beyond the arm's reach
        let opts = IkOptions::new(3, Isometry3::identity());
        let starts = vec![0.0; k * targets.len()];
        let run = |t| {
            rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap().install(|| ik(&model, &targets, &starts, &[], &opts).unwrap())
        };
        let (one, two) = (run(1), run(2));
        for (a, b) in one.iter().zip(&two) {
            assert_eq!(a.pose, b.pose);
        }
        for a in &one[..4] {
            assert_eq!(a.outcome, IkOutcome::Certified, "{a:?}");
            assert!(a.pos_err <= 1e-6 && a.rot_err <= 1e-6);
        }
        assert_eq!(one[4].outcome, IkOutcome::Unreachable);
        assert!(!one[4].reached && one[4].pos_err > 1.0);
    }
}
