//! Timed paths: a waypoint path crossed within each joint's velocity and acceleration limits,
//! its corners rounded by parabolic blends and cut by chords, every blend and chord kept proven
//! free by the continuous certificate ([`super::motion`]). `profrobot.time_path` (Python) gates
//! the arguments, unwraps the path and keeps the jerk-limited profile; this is its search.
//!
//! Per run of waypoints `W_0 … W_n` between two stops (at rest at both ends), `D_i = W_{i+1} −
//! W_i` (unwrapped: short arcs on continuous hinges), limits `v_j`, `a_j`:
//!
//! 1. Segment `i` is crossed at the constant velocity `V_i = D_i / T_i`, `T_i ≥ max_j |D_ij|/v_j`.
//! 2. At waypoint `i` the velocity changes from `V_{i−1}` to `V_i` (`V_{−1} = V_n = 0`) at the
//!    constant acceleration `(V_i − V_{i−1}) / τ_i` over `τ_i = max_j |V_ij − V_{i−1,j}| / a_j`,
//!    centred on the waypoint's time: the quadratic Bézier `W_i − V_{i−1}τ_i/2 → W_i → W_i +
//!    V_iτ_i/2`, proven as a curve (`certify_as_given`; the first timing's blends in one batch with
//!    the path's parts, `certify_given`); one that is not becomes a stop.
//! 3. A segment holds half of each blend beside it: `τ_i/2 + τ_{i+1}/2 ≤ T_i`. The times start
//!    from every segment at its velocity limit and from a ramp (`ramp`), and a segment whose
//!    blends do not fit is slowed by `√(need / T_i)` (the exact answer for a lone segment) until
//!    they do (`settle`); the quicker settled start is kept. After `ROUNDS` rounds a run still
//!    unsettled stops at every waypoint.
//!
//! Step 0, corner cuts (`cuts`): a chord from `W_i − D_{i−1}·c` to `W_i + D_i·c` is quicker
//! than the two half-segments it replaces wherever different joints lead them; the widest of
//! `cut`, `cut/2`, `cut/4` whose chord is proven replaces the corner, and the cut path is timed
//! as above. It is kept when it is certified and the uncut path is not, or as certified and
//! not slower (the uncut path timed only when its best case, every blend proven, could be
//! quicker, or when the cut path is not certified).
//!
//! What is proven is what the robot crosses: the chords, the parts of the path's segments
//! between them (`Part::Along`; none where two chords of half a segment meet at its middle)
//! and the blends kept, each proof from the curve's middle first (`Order::MiddleFirst`: their
//! ends lie on the path's motions, so most pairs close from the middle alone). Velocity is piecewise linear and acceleration piecewise constant, each
//! within its limit by construction; the cruise parts lie on those segments and chords, so the
//! timed motion is certified when every part crossed is (`first_unproven`). A part on a
//! segment this model has proven whole, at this clearance, is not proven again
//! (`model::proven::ProvenLines`: the segments `plan_path` proved, and those an earlier timing
//! proved to cover a part): its poses are the segment's. Every verdict is the certificate's of
//! one motion alone, so the result does not depend on the thread count; proven again, such a
//! part is certified alone or through its segment (`first_unproven`), so the timing is the same
//! either way (`ProvenLines` says where an ulp could tell them apart), as the tests check.

use std::collections::HashMap;

use crate::error::{Error, Result};
use crate::model::RobotModel;
use crate::planning::motion::{certify_as_given, certify_given, first_certified, Motion, Order, Verdicts};

/// Speed fractions the ramp tries, fastest first: `1 − i/GRID` for `i < GRID` (exact in binary).
const GRID: usize = 64;
/// Rounds of `settle` before a run stops at every waypoint.
const ROUNDS: usize = 200;

#[inline]
fn grid(i: usize) -> f64 {
    1.0 - i as f64 / GRID as f64
}

/// A timed path: pieces of constant acceleration, in unwrapped joint coordinates.
#[derive(Clone, Debug)]
pub struct Timed {
    /// `(M, K)` the waypoints timed: the path given, each cut corner replaced by its chord's ends.
    pub waypoints: Vec<f64>,
    /// `(P,)` seconds: each piece's start.
    pub starts: Vec<f64>,
    /// `(P, K)` position, velocity and acceleration at each piece's start.
    pub q0: Vec<f64>,
    pub v0: Vec<f64>,
    pub acc: Vec<f64>,
    /// Seconds from the first waypoint to the last.
    pub duration: f64,
    /// `(M,)` seconds at each stop, or halfway through the blend at each corner.
    pub times: Vec<f64>,
    /// `(M,)` the waypoints reached at rest.
    pub stops: Vec<bool>,
    /// Where the timed motion is not certified: the first segment of the path given whose part
    /// it crosses (`Part::Along`) is not certified, and the verdict; None when every pose of
    /// the timed motion is certified (the parts crossed, every chord and every blend kept).
    pub unproven: Option<(usize, Motion)>,
}

/// The pieces of one timing of a path with given stops (`pieces`).
struct Pieces {
    starts: Vec<f64>,
    q0: Vec<f64>,
    v0: Vec<f64>,
    acc: Vec<f64>,
    duration: f64,
    times: Vec<f64>,
    stops: Vec<bool>,
    /// Each interior corner blended: its index and control points `(start, via, goal)`, `3K`.
    blends: Vec<(usize, Vec<f64>)>,
}

/// What every timing of one call shares: the joint count and the limits.
struct Limits<'a> {
    k: usize,
    v: &'a [f64],
    a: &'a [f64],
}

impl Limits<'_> {
    /// `max_j |x_j| / l_j`.
    #[inline]
    fn lead(&self, x: impl Iterator<Item = f64>, l: &[f64]) -> f64 {
        x.zip(l).fold(0.0f64, |m, (x, l)| m.max(x.abs() / l))
    }

    /// Each segment's time at its velocity limit, `max_j |D_ij| / v_j`.
    fn t_min(&self, d: &[f64]) -> Vec<f64> {
        d.chunks_exact(self.k).map(|di| self.lead(di.iter().copied(), self.v)).collect()
    }

    /// Per segment, a speed fraction `s` (of its velocity-limited speed) with every blend inside
    /// half of each segment beside it, `τ_i ≤ min(T_{i−1}, T_i)` for `T_i = t_min_i / s_i` (a
    /// sufficient form of step 3, local to one corner): a forward pass from rest and a backward
    /// one to rest, each taking at every corner the fastest fraction of the grid that fits; their
    /// minimum. Over many short segments this ramps the speed up and down across segments, where
    /// slowing each violating segment alone slows them all.
    fn ramp(&self, d: &[f64], t_min: &[f64]) -> Vec<f64> {
        let k = self.k;
        let n = t_min.len();
        let u: Vec<f64> = d.chunks_exact(k).zip(t_min).flat_map(|(di, &t)| di.iter().map(move |x| x / t)).collect();
        let fastest = |prev_v: &[f64], prev_t: f64, i: usize| -> f64 {
            let ui = &u[i * k..(i + 1) * k];
            (0..GRID)
                .map(grid)
                .find(|&g| {
                    let tau = self.lead(ui.iter().zip(prev_v).map(|(u, p)| g * u - p), self.a);
                    tau <= prev_t && tau <= t_min[i] / g
                })
                .unwrap_or(grid(GRID - 1))
        };
        let pass = |order: &mut dyn Iterator<Item = usize>| {
            let mut s = vec![0.0; n];
            let (mut prev_v, mut prev_t) = (vec![0.0; k], f64::INFINITY);
            for i in order {
                s[i] = fastest(&prev_v, prev_t, i);
                for (p, u) in prev_v.iter_mut().zip(&u[i * k..(i + 1) * k]) {
                    *p = s[i] * u;
                }
                prev_t = t_min[i] / s[i];
            }
            s
        };
        let fwd = pass(&mut (0..n));
        let bwd = pass(&mut (0..n).rev());
        fwd.iter().zip(&bwd).map(|(f, b)| f.min(*b)).collect()
    }

    /// The blend times `τ_0 … τ_n` of segments `d` crossed in times `t`, into `tau`; `vel`
    /// holds the segments' velocities `D_i / T_i` (each computed once, not at both its corners).
    fn blend_times(&self, d: &[f64], t: &[f64], vel: &mut Vec<f64>, tau: &mut Vec<f64>) {
        let k = self.k;
        vel.clear();
        vel.extend(d.chunks_exact(k).zip(t).flat_map(|(di, ti)| di.iter().map(move |x| x / ti)));
        vel.resize((t.len() + 1) * k, 0.0);
        tau.clear();
        tau.push(self.lead(vel[..k].iter().copied(), self.a));
        tau.extend(vel.windows(2 * k).step_by(k).map(|w| self.lead((0..k).map(|j| w[k + j] - w[j]), self.a)));
    }

    /// The blend time at corner `c` from the segments' velocities `vel` (`blend_times`' `τ_c`,
    /// bit for bit).
    #[inline]
    fn corner(&self, vel: &[f64], c: usize) -> f64 {
        let k = self.k;
        if c == 0 {
            self.lead(vel[..k].iter().copied(), self.a)
        } else {
            self.lead((0..k).map(|j| vel[c * k + j] - vel[(c - 1) * k + j]), self.a)
        }
    }

    /// Step 3 from segment times `t`: each segment whose blends do not fit slowed until they do;
    /// `(t, τ)`, or None when `ROUNDS` rounds do not settle. Each round slows every segment
    /// whose ratio is over 1 at once, from the ratios of the round before; what a slowed segment
    /// changes (its velocity, the blends at its two corners, the ratios of the segments beside
    /// them) is computed again, by the same formulas, and nothing else: the rounds of computing
    /// every velocity and blend anew, bit for bit, at the cost of the segments that move (a few,
    /// after the first rounds).
    fn settle(&self, d: &[f64], mut t: Vec<f64>) -> Option<(Vec<f64>, Vec<f64>)> {
        let (k, n) = (self.k, t.len());
        let (mut vel, mut tau) = (Vec::new(), Vec::new());
        self.blend_times(d, &t, &mut vel, &mut tau);
        let ratio = |tau: &[f64], i: usize, ti: f64| 0.5 * (tau[i] + tau[i + 1]) / ti;
        let mut ratios: Vec<f64> = (0..n).map(|i| ratio(&tau, i, t[i])).collect();
        let mut moved = Vec::with_capacity(n);
        for _ in 0..ROUNDS {
            // (a NaN ratio is not settled, and does not move)
            if ratios.iter().all(|&r| r <= 1.0 + 1e-12) {
                return Some((t, tau));
            }
            moved.clear();
            for (i, ti) in t.iter_mut().enumerate() {
                let r = ratios[i];
                if r > 1.0 {
                    *ti = *ti * r.sqrt() * (1.0 + 1e-12);
                    moved.push(i);
                }
            }
            for &i in &moved {
                for j in 0..k {
                    vel[i * k + j] = d[i * k + j] / t[i];
                }
            }
            for &i in &moved {
                tau[i] = self.corner(&vel, i);
                tau[i + 1] = self.corner(&vel, i + 1);
            }
            for &i in &moved {
                for s in i.saturating_sub(1)..(i + 2).min(n) {
                    ratios[s] = ratio(&tau, s, t[s]);
                }
            }
        }
        None
    }

    /// Segment times and blend times of one run (steps 1-3): settled from every segment at its
    /// velocity limit and from the ramp, the quicker kept (the times summed in order; numpy's
    /// pairwise sum, in the Python this replaces, could keep the other on a near-tie of 8
    /// segments or more); None when neither settles.
    fn run_times(&self, d: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
        let t_min = self.t_min(d);
        let ramped: Vec<f64> = t_min.iter().zip(self.ramp(d, &t_min)).map(|(t, s)| t / s).collect();
        let cost = |(t, tau): &(Vec<f64>, Vec<f64>)| t.iter().sum::<f64>() + 0.5 * (tau[0] + tau[tau.len() - 1]);
        let mut best: Option<(Vec<f64>, Vec<f64>)> = None;
        for start in [t_min, ramped] {
            if let Some(got) = self.settle(d, start) {
                if best.as_ref().is_none_or(|b| cost(&got) < cost(b)) {
                    best = Some(got);
                }
            }
        }
        best
    }

    /// One segment alone, from rest to rest: `run_times`, or (should it not settle) the
    /// trapezoid `T = max(max_j |D_j|/v_j, √(max_j |D_j|/a_j))`, whose blends fit by construction.
    fn lone(&self, d: &[f64]) -> (Vec<f64>, Vec<f64>) {
        self.run_times(d).unwrap_or_else(|| {
            let t = self.lead(d.iter().copied(), self.v).max(self.lead(d.iter().copied(), self.a).sqrt());
            let tau = self.lead(d.iter().map(|x| x / t), self.a);
            (vec![t], vec![tau, tau])
        })
    }

    /// The pieces of the path `w` (`(M, K)`) stopping at `stops` (and, per run that does not
    /// settle, at every waypoint of it), the waypoints' times and each corner's blend.
    fn pieces(&self, w: &[f64], stops: &[bool]) -> Pieces {
        let k = self.k;
        let m = stops.len();
        let mut out = Pieces {
            starts: Vec::new(),
            q0: Vec::new(),
            v0: Vec::new(),
            acc: Vec::new(),
            duration: 0.0,
            times: vec![0.0; m],
            stops: stops.to_vec(),
            blends: Vec::new(),
        };
        let mut cut: Vec<usize> = vec![0];
        cut.extend((1..m - 1).filter(|&i| stops[i]));
        cut.push(m - 1);
        let mut clock = 0.0;
        for r in cut.windows(2) {
            let (r0, r1) = (r[0], r[1]);
            let d: Vec<f64> = (r0 * k..r1 * k).map(|x| w[x + k] - w[x]).collect();
            match self.run_times(&d) {
                Some((t, tau)) => {
                    clock = out.run(w, r0, &t, &tau, clock, k, true);
                }
                None => {
                    // (the run stops at every waypoint; each segment alone)
                    for i in r0..r1 {
                        out.stops[i] = true;
                        out.stops[i + 1] = true;
                        let (t, tau) = self.lone(&d[(i - r0) * k..(i - r0 + 1) * k]);
                        let first = out.starts.len();
                        let end = out.run(w, i, &t, &tau, 0.0, k, false);
                        for s in &mut out.starts[first..] {
                            *s += clock;
                        }
                        out.times[i] = clock;
                        clock += end;
                    }
                    out.times[r1] = clock;
                }
            }
        }
        out.duration = clock;
        out
    }
}

impl Pieces {
    /// Appends the pieces of the run from waypoint `r0` crossed in segment times `t` with blend
    /// times `tau`, starting at `clock`; returns the clock at its end. With `corners`, the
    /// run's waypoints' times and its interior blends are recorded.
    #[allow(clippy::too_many_arguments)]
    fn run(&mut self, w: &[f64], r0: usize, t: &[f64], tau: &[f64], clock: f64, k: usize, corners: bool) -> f64 {
        let n = t.len();
        // (the velocity before waypoint `i` of the run: of segment `i − 1`, at rest outside)
        let vel = |i: usize, j: usize| {
            if i == 0 || i > n {
                0.0
            } else {
                (w[(r0 + i) * k + j] - w[(r0 + i - 1) * k + j]) / t[i - 1]
            }
        };
        // (the waypoint times: the first blend's half, then each segment; summed in order)
        let mut centre = Vec::with_capacity(n + 1);
        let (base, mut sum) = (clock + tau[0] / 2.0, 0.0);
        centre.push(base + 0.0);
        for ti in t {
            sum += ti;
            centre.push(base + sum);
        }
        for i in 0..=n {
            let wi = &w[(r0 + i) * k..(r0 + i + 1) * k];
            if tau[i] > 0.0 {
                self.starts.push(centre[i] - tau[i] / 2.0);
                for (j, x) in wi.iter().enumerate() {
                    let (vin, vout) = (vel(i, j), vel(i + 1, j));
                    self.q0.push(x - vin * tau[i] / 2.0);
                    self.v0.push(vin);
                    self.acc.push((vout - vin) / tau[i]);
                }
                if corners && 0 < i && i < n {
                    let mut ctl = Vec::with_capacity(3 * k);
                    ctl.extend((0..k).map(|j| wi[j] - vel(i, j) * tau[i] / 2.0));
                    ctl.extend_from_slice(wi);
                    ctl.extend((0..k).map(|j| wi[j] + vel(i + 1, j) * tau[i] / 2.0));
                    self.blends.push((r0 + i, ctl));
                }
            }
            if i < n {
                let cruise = centre[i] + tau[i] / 2.0;
                if centre[i + 1] - tau[i + 1] / 2.0 > cruise {
                    self.starts.push(cruise);
                    for (j, x) in wi.iter().enumerate() {
                        let vout = vel(i + 1, j);
                        self.q0.push(x + vout * tau[i] / 2.0);
                        self.v0.push(vout);
                        self.acc.push(0.0);
                    }
                }
            }
        }
        let end = centre[n] + tau[n] / 2.0;
        if corners {
            self.times[r0 + 1..r0 + n].copy_from_slice(&centre[1..n]);
            self.times[r0] = clock;
            self.times[r0 + n] = end;
        }
        end
    }
}

/// Whether each motion `starts[i] → goals[i]` is certified.
fn proven(model: &RobotModel, starts: &[f64], goals: &[f64], clearance: f64) -> Result<Vec<bool>> {
    if starts.is_empty() {
        return Ok(Vec::new());
    }
    Ok(certify_as_given(model, starts, None, goals, clearance, Order::MiddleFirst)?
        .iter()
        .map(|(m, _)| matches!(m, Motion::Certified))
        .collect())
}

/// Rows `idx` of the `(M, K)` row-major `x`, row-major.
fn rows(x: &[f64], k: usize, idx: impl Iterator<Item = usize>) -> Vec<f64> {
    idx.flat_map(|i| x[i * k..(i + 1) * k].iter().copied()).collect()
}

/// Blends proven or refuted in one call, by their control points' bits: each is proven once.
type Memo = HashMap<Vec<u64>, bool>;

fn memo_key(c: &[f64]) -> Vec<u64> {
    c.iter().map(|x| x.to_bits()).collect()
}

/// Records the certificate's `verdicts` on `blends` (their control points) in `memo`.
fn remember(memo: &mut Memo, blends: &[&Vec<f64>], verdicts: Verdicts) {
    for (c, (verdict, _)) in blends.iter().zip(verdicts) {
        memo.insert(memo_key(c), matches!(verdict, Motion::Certified));
    }
}

/// The control points of `blends` as three `(B, K)` arrays: starts, vias, goals.
fn controls(k: usize, blends: &[&Vec<f64>]) -> [Vec<f64>; 3] {
    let part = |s: usize| blends.iter().flat_map(|c| c[s * k..(s + 1) * k].iter().copied()).collect::<Vec<f64>>();
    [part(0), part(1), part(2)]
}

/// The pieces with every corner blended whose blend is proven free and the others stops (all
/// stops without `blend`): from `first` (the pieces of that start), corners whose blend fails
/// become stops and the runs beside them are timed again, until every blend left is proven
/// (each blend proven once per call: `memo`, which may hold some already).
fn blended(model: &RobotModel, lim: &Limits, w: &[f64], first: Pieces, memo: &mut Memo, clearance: f64) -> Result<Pieces> {
    let mut p = first;
    loop {
        let todo: Vec<&Vec<f64>> = p.blends.iter().map(|(_, c)| c).filter(|c| !memo.contains_key(&memo_key(c))).collect();
        if !todo.is_empty() {
            let [s, v, g] = controls(lim.k, &todo);
            remember(memo, &todo, certify_as_given(model, &s, Some(&v), &g, clearance, Order::MiddleFirst)?);
        }
        let failed: Vec<usize> = p.blends.iter().filter(|(_, c)| !memo[&memo_key(c)]).map(|&(i, _)| i).collect();
        if failed.is_empty() {
            return Ok(p);
        }
        let mut stops = p.stops;
        for i in failed {
            stops[i] = true;
        }
        p = lim.pieces(w, &stops);
    }
}

/// The timing of waypoints `w` (`blended`, from every corner blended, or with `blend` false
/// every waypoint a stop) and the first part of the path it crosses that is not proven
/// (`first_unproven`; `parts` says what each segment of `w` lies on). The parts and the first
/// timing's blends are proven in one batch (`certify_given`): neither waits for the other.
fn proven_timing(
    model: &RobotModel,
    lim: &Limits,
    path: &[f64],
    w: &[f64],
    parts: &[Part],
    blend: bool,
    clearance: f64,
) -> Result<(Pieces, Option<(usize, Motion)>)> {
    let k = lim.k;
    let m = w.len() / k;
    let mut stops = vec![!blend; m];
    stops[0] = true;
    stops[m - 1] = true;
    let first = lim.pieces(w, &stops);
    let along = along(parts);
    // (a part on a segment this model has proven whole is proven: `ProvenLines`)
    let known: Vec<bool> = along.iter().map(|&(_, j)| segment_proven(model, k, path, j, clearance)).collect();
    let todo = || along.iter().zip(&known).filter(|(_, &known)| !known).map(|(&(i, _), _)| i);
    let ends = |d: usize| rows(w, k, todo().map(|i| i + d));
    let blends: Vec<&Vec<f64>> = first.blends.iter().map(|(_, c)| c).collect();
    let [s, v, g] = controls(k, &blends);
    let (parts_proven, blends_proven) = certify_given(model, [&ends(0), &ends(1)], [&s, &v, &g], clearance, Order::MiddleFirst)?;
    let mut alone = parts_proven.into_iter();
    let parts_proven: Verdicts =
        known.iter().map(|&known| if known { (Motion::Certified, 0) } else { alone.next().expect("a verdict a part") }).collect();
    let mut memo = Memo::new();
    remember(&mut memo, &blends, blends_proven);
    let unproven = first_unproven(model, k, path, w, &along, parts_proven, clearance)?;
    Ok((blended(model, lim, w, first, &mut memo, clearance)?, unproven))
}

/// Per waypoint, the share of its segments its corner is cut by (step 0): the widest of `cut`,
/// `cut/2`, `cut/4` whose chord from `W_i − D_{i−1}·f` to `W_i + D_i·f` is proven, 0 where none is (and at the
/// ends). A continuous hinge's chord must be the short arc the certificate proves.
fn cuts(model: &RobotModel, k: usize, w: &[f64], cut: f64, clearance: f64) -> Result<Vec<f64>> {
    let m = w.len() / k;
    let wraps = model.continuous();
    let shares = [cut, cut / 2.0, cut / 4.0];
    // Each corner tries its chords in turn, the corners in parallel (a corner whose widest
    // chord is blocked tries the next at once, not after every corner's first).
    // (task `i` is corner `i + 1`)
    let first = first_certified(
        model,
        m.saturating_sub(2),
        &|i| format!("the chord of corner {}", i + 1),
        clearance,
        Order::MiddleFirst,
        |i, n, p0, p1| {
            let f = *shares.get(n)?;
            let (a, b, c) = (&w[i * k..(i + 1) * k], &w[(i + 1) * k..(i + 2) * k], &w[(i + 2) * k..(i + 3) * k]);
            for j in 0..k {
                p0[j] = a[j] + (b[j] - a[j]) * (1.0 - f);
                p1[j] = b[j] + (c[j] - b[j]) * f;
            }
            Some((0..k).all(|j| !wraps[j] || (p1[j] - p0[j]).abs() < std::f64::consts::PI - 1e-6))
        },
    )?;
    let mut share = vec![0.0; m];
    for (i, n) in first.into_iter().enumerate() {
        if let Some(n) = n {
            share[i + 1] = shares[n];
        }
    }
    Ok(share)
}

/// What a segment of the timed waypoints lies on: a corner's chord (proven by `cuts`), or a
/// part of the path's segment `j`.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Part {
    Chord,
    Along(usize),
}

/// The waypoints with corner `i` (`share[i] > 0`) replaced by the two ends of its chord, each
/// written as a point of its segment, `W_j + D_j·s` (the form `cuts` proves); two ends that
/// meet (at the middle of a segment) are one waypoint. And what each of their segments lies on.
fn cut_points(k: usize, w: &[f64], share: &[f64]) -> (Vec<f64>, Vec<Part>) {
    let m = share.len();
    let mut out = w[..k].to_vec();
    let mut parts = Vec::with_capacity(2 * m);
    for j in 0..m - 1 {
        let (a, b) = (&w[j * k..(j + 1) * k], &w[(j + 1) * k..(j + 2) * k]);
        let (s_out, s_in) = (share[j], 1.0 - share[j + 1]);
        let at = |s: f64| (0..k).map(move |i| a[i] + (b[i] - a[i]) * s);
        if s_out > 0.0 {
            out.extend(at(s_out));
            parts.push(Part::Chord);
        }
        if share[j + 1] > 0.0 && s_in != s_out {
            out.extend(at(s_in));
            parts.push(Part::Along(j));
        }
        if share[j + 1] == 0.0 {
            out.extend_from_slice(b);
            parts.push(Part::Along(j));
        }
    }
    (out, parts)
}

/// The segments of `w` that lie on the path's segments (`parts`, chords aside): each one's
/// index in `w` and the path's segment it lies on.
fn along(parts: &[Part]) -> Vec<(usize, usize)> {
    parts
        .iter()
        .enumerate()
        .filter_map(|(i, p)| match p {
            Part::Along(j) => Some((i, *j)),
            Part::Chord => None,
        })
        .collect()
}

/// Segment `j` of the path `path` (`(M, K)`) as `certify_as_given` proves it: its start `W_j`
/// and its step `W_{j+1} − W_j`.
fn segment(path: &[f64], k: usize, j: usize) -> (&[f64], Vec<f64>) {
    let (a, b) = (&path[j * k..(j + 1) * k], &path[(j + 1) * k..(j + 2) * k]);
    (a, a.iter().zip(b).map(|(a, b)| b - a).collect())
}

/// Whether this model has proven segment `j` of the path `path` whole at `clearance`
/// (`ProvenLines`: `plan_path`'s segments, and those an earlier `time_path` proved).
fn segment_proven(model: &RobotModel, k: usize, path: &[f64], j: usize, clearance: f64) -> bool {
    let (a, delta) = segment(path, k, j);
    model.proven_lines.holds(a, &delta, clearance)
}

/// The first segment of `w` (`(M, K)`) along the path `path` (`along`, with the certificate's
/// `verdicts` on them) that is not proven: the path's segment it lies on, and the verdict on
/// it. The chords are proven already; so the timed motion crosses only proven segments when
/// this is None. A part the certificate does not certify on its own is proven still when its
/// whole segment is (its poses are among the segment's: proving a shorter motion can stop where
/// the longer did not, at the certificate's state budget).
fn first_unproven(
    model: &RobotModel,
    k: usize,
    path: &[f64],
    w: &[f64],
    along: &[(usize, usize)],
    verdicts: Verdicts,
    clearance: f64,
) -> Result<Option<(usize, Motion)>> {
    debug_assert_eq!(along.len(), verdicts.len());
    let failed: Vec<(usize, Motion)> =
        along.iter().zip(verdicts).filter(|(_, (v, _))| !matches!(v, Motion::Certified)).map(|(&(_, j), (v, _))| (j, v)).collect();
    // (the segments of the failed parts that are not whole segments themselves)
    let whole = |j: usize| w.len() == path.len() && w[j * k..(j + 2) * k] == path[j * k..(j + 2) * k];
    let mut segments: Vec<usize> = failed.iter().map(|&(j, _)| j).filter(|&j| !whole(j)).collect();
    segments.dedup();
    let whole_ok: Vec<bool> =
        proven(model, &rows(path, k, segments.iter().copied()), &rows(path, k, segments.iter().map(|j| j + 1)), clearance)?;
    for (&j, _) in segments.iter().zip(&whole_ok).filter(|(_, &ok)| ok) {
        let (a, delta) = segment(path, k, j);
        model.proven_lines.insert(a, &delta, clearance);
    }
    let rescued = |j: usize| segments.iter().position(|&s| s == j).is_some_and(|i| whole_ok[i]);
    Ok(failed.into_iter().find(|&(j, _)| !rescued(j)))
}

/// Times the path `path` (`(M, K)` row-major, M ≥ 2, unwrapped: each segment is crossed, and
/// proven, as given, `W_i + D_i·s` on every joint; no zero-length segment) within `velocity` and
/// `acceleration` (`(K,)`, positive), blending the corners whose blends are proven (stopping at
/// every waypoint without `blend`) and, with `cut` in `(0, 0.5]`, cutting corners by proven
/// chords (module docs). Every proof keeps `max(margin, clearance)` metres, and every part of
/// the path the timed motion crosses is proven (`Timed::unproven`), in parallel on rayon's
/// current pool.
pub fn time_path(
    model: &RobotModel,
    path: &[f64],
    velocity: &[f64],
    acceleration: &[f64],
    blend: bool,
    cut: f64,
    clearance: f64,
) -> Result<Timed> {
    let k = model.njoint();
    let m = model.check_poses(path)?;
    if m < 2 {
        return Err(Error::InvalidInput(format!("path must hold at least two waypoints; got {m}")));
    }
    for (name, x) in [("velocity", velocity), ("acceleration", acceleration)] {
        if x.len() != k || !x.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(Error::InvalidInput(format!("{name} must be {k} positive finite limits")));
        }
    }
    if !(0.0..=0.5).contains(&cut) {
        return Err(Error::InvalidInput(format!("cut must be a share of each segment in [0, 0.5]; got {cut}")));
    }
    if (0..m - 1).any(|i| (0..k).all(|j| path[i * k + j] == path[(i + 1) * k + j])) {
        return Err(Error::InvalidInput("path must hold no zero-length segment".into()));
    }
    // (the crew's helpers awake for the sections ahead, from here on)
    let _awake = crate::threads::crew_awake();
    let lim = Limits { k, v: velocity, a: acceleration };
    let share = if blend && cut > 0.0 && m > 2 { cuts(model, k, path, cut, clearance)? } else { vec![0.0; m] };
    let whole: Vec<Part> = (0..m - 1).map(Part::Along).collect();
    let (timed, waypoints, unproven) = if share.iter().any(|&s| s > 0.0) {
        let (wc, parts) = cut_points(k, path, &share);
        let (timed, unproven) = proven_timing(model, &lim, path, &wc, &parts, true, clearance)?;
        let mut ends = vec![false; m];
        ends[0] = true;
        ends[m - 1] = true;
        // The cut path is kept outright when it is certified and no timing of the uncut path
        // could be quicker (every blend proven, at best); else the uncut path where it is
        // certified and the cut one is not, or as certified and quicker.
        // (no timing of the uncut path is quicker than its segments each at its velocity limit:
        // `pieces`' segment times are at least `t_min` each, its duration their sum and the end
        // blends', so a cut path within `Σ t_min`, less a rounding margin, needs no `pieces`)
        let floor = || {
            let d: Vec<f64> = (0..(m - 1) * k).map(|x| path[x + k] - path[x]).collect();
            lim.t_min(&d).iter().sum::<f64>() * (1.0 - 1e-9)
        };
        if unproven.is_some() || (timed.duration > floor() && timed.duration > lim.pieces(path, &ends).duration) {
            let (uncut, uncut_unproven) = proven_timing(model, &lim, path, path, &whole, true, clearance)?;
            let better = match (uncut_unproven.is_none(), unproven.is_none()) {
                (true, false) => true,
                (false, true) => false,
                _ => uncut.duration < timed.duration,
            };
            if better {
                (uncut, path.to_vec(), uncut_unproven)
            } else {
                (timed, wc, unproven)
            }
        } else {
            (timed, wc, unproven)
        }
    } else {
        let (timed, unproven) = proven_timing(model, &lim, path, path, &whole, blend, clearance)?;
        (timed, path.to_vec(), unproven)
    };
    Ok(Timed {
        waypoints,
        starts: timed.starts,
        q0: timed.q0,
        v0: timed.v0,
        acc: timed.acc,
        duration: timed.duration,
        times: timed.times,
        stops: timed.stops,
        unproven,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::collide::Scratch;
    use crate::collision::fastpath::certified_pose;
    use crate::planning::motion::tests::cluttered_arm;
    use crate::threads::with_threads;
    use rand::{Rng, SeedableRng};

    /// Position and velocity of piece `p` of `t` at `tau` seconds into it, joint `j`.
    fn at(t: &Timed, k: usize, p: usize, j: usize, tau: f64) -> (f64, f64) {
        let (q0, v0, a) = (t.q0[p * k + j], t.v0[p * k + j], t.acc[p * k + j]);
        (q0 + v0 * tau + 0.5 * a * tau * tau, v0 + a * tau)
    }

    /// The pose at time `time` (the piece it falls in).
    fn pose(t: &Timed, k: usize, time: f64) -> Vec<f64> {
        let p = t.starts.partition_point(|&s| s <= time).max(1) - 1;
        (0..k).map(|j| at(t, k, p, j, time - t.starts[p]).0).collect()
    }

    /// A planned path's segments are recorded as proven (`ProvenLines`: at the plan's clearance,
    /// not at another, and not on another model), and timing the path reads them instead of
    /// proving its parts again: the same timed motion, bit for bit, as on a model that never
    /// planned and proves every part itself, with the corners kept (parts only) and cut.
    #[test]
    fn planned_segments_are_not_proven_again() {
        use crate::planning::plan::{plan_path, PlanOptions};
        let (planner, fresh) = (cluttered_arm(), cluttered_arm());
        let k = planner.njoint();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut s = Scratch::new(&planner);
        let mut free = || loop {
            let q: Vec<f64> = (0..k).map(|j| rng.random_range(planner.limits[j][0]..planner.limits[j][1])).collect();
            if certified_pose(&planner, &q, 1e-6, &mut s).unwrap() {
                return q;
            }
        };
        let (mut planned, mut parts, mut recorded) = (0, 0, 0);
        for case in 0..12 {
            let (start, goal) = (free(), free());
            let opts = PlanOptions { clearance: 1e-6, seed: case, ..PlanOptions::default() };
            let path = plan_path(&planner, &start, &goal, &opts).unwrap().path;
            let m = path.len() / k;
            if m < 3 {
                continue;
            }
            planned += 1;
            let before = planner.proven_lines.len();
            for j in 0..m - 1 {
                // (a repair's segments are not recorded: its search proves some edges backwards)
                let (a, delta) = segment(&path, k, j);
                recorded += planner.proven_lines.holds(a, &delta, 1e-6) as usize;
                assert!(!planner.proven_lines.holds(a, &delta, 5e-7) && !planner.proven_lines.holds(a, &delta, 2e-6));
                assert!(!fresh.proven_lines.holds(a, &delta, 1e-6));
            }
            let (v, acc) = (vec![1.5; k], vec![3.0; k]);
            for cut in [0.0, 0.5] {
                let ours = time_path(&planner, &path, &v, &acc, true, cut, 1e-6).unwrap();
                let theirs = time_path(&fresh, &path, &v, &acc, true, cut, 1e-6).unwrap();
                assert_eq!(format!("{ours:?}"), format!("{theirs:?}"), "case {case} cut {cut}");
                assert!(ours.unproven.is_none(), "case {case} cut {cut}");
                parts += (cut == 0.0) as usize * (m - 1);
            }
            // (timing reads the plan's proofs; it writes only whole segments it proves itself)
            assert_eq!(planner.proven_lines.len(), before, "case {case}");
        }
        assert!(planned >= 4 && parts >= 12, "{planned} paths planned, {parts} parts");
        assert!(2 * recorded >= parts, "{recorded} of {parts} segments recorded");
        // The record itself: a motion by its start, step and clearance, bit for bit; emptied
        // when full.
        let lines = crate::model::proven::ProvenLines::default();
        let (a, d) = ([0.1, 0.2], [0.3, -0.4]);
        lines.insert(&a, &d, 2e-7);
        lines.insert(&a, &d, 1e-6);
        assert!(lines.holds(&a, &d, 1e-6) && lines.holds(&a, &d, 2e-7) && !lines.holds(&a, &d, 5e-7));
        assert!(!lines.holds(&a, &[0.3, f64::from_bits((-0.4f64).to_bits() + 1)], 1e-6) && !lines.holds(&d, &a, 1e-6));
        for i in 0..crate::model::proven::PROVEN_LINES {
            lines.insert(&[i as f64, 0.0], &d, 1e-6);
        }
        assert!(lines.len() <= 2 && !lines.holds(&a, &d, 1e-6) && !lines.holds(&a, &d, 2e-7));
    }

    /// Random paths among the boxes, timed under random limits: the pieces join in position and
    /// velocity, no piece leaves a limit, the motion starts and ends at rest on the path's ends
    /// and reaches every stop at rest on its waypoint; where the path's segments are certified,
    /// every pose sampled along the timed motion (blends and chords included) is certified
    /// clear by the exact labeller; the result is bit for bit the same on one thread and two.
    #[test]
    fn timed_paths_keep_the_limits_join_up_and_stay_clear() {
        let model = cluttered_arm();
        let k = model.njoint();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut s = Scratch::new(&model);
        let (mut certified, mut blended, mut cut) = (0, 0, 0);
        for case in 0..60 {
            let m = rng.random_range(2..7);
            let mut path: Vec<f64> = Vec::new();
            for i in 0..m {
                for j in 0..k {
                    let [lo, hi] = model.limits[j];
                    let x =
                        if i == 0 { rng.random_range(lo..hi) } else { (path[(i - 1) * k + j] + rng.random_range(-0.8..0.8)).clamp(lo, hi) };
                    path.push(if j == 2 { x * 0.5 } else { x });
                }
            }
            let v: Vec<f64> = (0..k).map(|_| rng.random_range(0.5..2.0)).collect();
            let a: Vec<f64> = (0..k).map(|_| rng.random_range(1.0..10.0)).collect();
            let cut_share = [0.0, 0.5, 0.25][case % 3];
            let one = with_threads(Some(1), || time_path(&model, &path, &v, &a, true, cut_share, 1e-6)).unwrap().unwrap();
            let two = with_threads(Some(2), || time_path(&model, &path, &v, &a, true, cut_share, 1e-6)).unwrap().unwrap();
            assert_eq!(format!("{one:?}"), format!("{two:?}"), "case {case}");
            let t = one;
            let n = t.starts.len();
            assert_eq!(t.starts[0], 0.0);
            for p in 0..n {
                let end = if p + 1 < n { t.starts[p + 1] } else { t.duration };
                assert!(end >= t.starts[p]);
                for j in 0..k {
                    assert!(t.acc[p * k + j].abs() <= a[j] * (1.0 + 1e-9), "case {case} piece {p}");
                    let (q, qd) = at(&t, k, p, j, end - t.starts[p]);
                    assert!(t.v0[p * k + j].abs() <= v[j] * (1.0 + 1e-9) && qd.abs() <= v[j] * (1.0 + 1e-9));
                    if p + 1 < n {
                        assert!(
                            (q - t.q0[(p + 1) * k + j]).abs() < 1e-9 && (qd - t.v0[(p + 1) * k + j]).abs() < 1e-9,
                            "case {case} piece {p}"
                        );
                    } else {
                        let last = t.waypoints.len() - k;
                        assert!((q - t.waypoints[last + j]).abs() < 1e-9 && qd.abs() < 1e-9);
                    }
                }
            }
            assert!((0..k).all(|j| t.q0[j] == path[j] && t.v0[j] == 0.0));
            let mw = t.stops.len();
            assert!(t.stops[0] && t.stops[mw - 1]);
            for i in (0..mw).filter(|&i| t.stops[i]) {
                let q = pose(&t, k, t.times[i]);
                assert!((0..k).all(|j| (q[j] - t.waypoints[i * k + j]).abs() < 1e-9), "case {case} stop {i}");
            }
            blended += t.stops.iter().filter(|s| !**s).count();
            cut += (t.waypoints.len() / k > m) as usize;
            if t.unproven.is_none() {
                certified += 1;
                for i in 0..=2000 {
                    let q = pose(&t, k, t.duration * i as f64 / 2000.0);
                    assert!(certified_pose(&model, &q, 1e-6, &mut s).unwrap(), "case {case} sample {i}");
                }
            }
        }
        assert!(certified >= 10 && blended >= 10 && cut >= 3, "{certified} certified, {blended} blends, {cut} cut");
    }

    /// `settle` recomputes only what its slowed segments change: the same times and blend times,
    /// bit for bit, and the same verdict, as rounds that compute every velocity and blend anew
    /// (the rule as first written), on random runs of 1 to 40 segments, long and short mixed,
    /// and runs with a zero-length segment, which never settle.
    #[test]
    fn settling_only_what_moved_is_settling_everything() {
        fn by_rounds(lim: &Limits, d: &[f64], mut t: Vec<f64>) -> Option<(Vec<f64>, Vec<f64>)> {
            let (mut vel, mut tau) = (Vec::new(), Vec::new());
            for _ in 0..ROUNDS {
                lim.blend_times(d, &t, &mut vel, &mut tau);
                let ratio = |tau: &[f64], i: usize, ti: f64| 0.5 * (tau[i] + tau[i + 1]) / ti;
                if t.iter().enumerate().all(|(i, &ti)| ratio(&tau, i, ti) <= 1.0 + 1e-12) {
                    return Some((t, tau));
                }
                for (i, ti) in t.iter_mut().enumerate() {
                    let r = ratio(&tau, i, *ti);
                    if r > 1.0 {
                        *ti = *ti * r.sqrt() * (1.0 + 1e-12);
                    }
                }
            }
            None
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let (mut settled, mut unsettled) = (0, 0);
        for case in 0..400 {
            let k = rng.random_range(1..8);
            let n = rng.random_range(1..40);
            let v: Vec<f64> = (0..k).map(|_| rng.random_range(0.3..3.0)).collect();
            let a: Vec<f64> = (0..k).map(|_| rng.random_range(0.5..10.0)).collect();
            let lim = Limits { k, v: &v, a: &a };
            let d: Vec<f64> = (0..n * k)
                .map(|_| {
                    let x: f64 = rng.random_range(-1.0..1.0);
                    if rng.random_bool(0.3) {
                        x * 1e-3
                    } else {
                        x
                    }
                })
                .collect();
            // (a zero-length segment has no time: its ratio is NaN, which never settles)
            let mut d = d;
            if case % 50 == 0 {
                let i = rng.random_range(0..n);
                d[i * k..(i + 1) * k].fill(0.0);
            }
            let t_min = lim.t_min(&d);
            let ramped: Vec<f64> = t_min.iter().zip(lim.ramp(&d, &t_min)).map(|(t, s)| t / s).collect();
            for start in [t_min, ramped] {
                let (ours, want) = (lim.settle(&d, start.clone()), by_rounds(&lim, &d, start));
                assert_eq!(format!("{ours:?}"), format!("{want:?}"), "case {case}");
                settled += want.is_some() as usize;
                unsettled += want.is_none() as usize;
            }
        }
        assert!(settled > 100 && unsettled > 0, "{settled} settled, {unsettled} not");
    }

    /// One joint crossing one segment alone takes the textbook trapezoid: `d/v + v/a` when it
    /// reaches `v`, else `2√(d/a)`.
    #[test]
    fn a_lone_segment_is_the_trapezoid() {
        let model = cluttered_arm();
        for (d, v, a, want) in [(1.0, 1.0, 2.0, 1.5), (0.1, 1.0, 2.0, 2.0 * (0.05f64).sqrt())] {
            let path = [0.0, 0.0, 0.0, 0.0, d, 0.0, 0.0, 0.0];
            let t = time_path(&model, &path, &[v; 4], &[a; 4], true, 0.5, 1e-6).unwrap();
            assert!((t.duration - want).abs() < 1e-9, "{} vs {want}", t.duration);
        }
    }

    /// Arguments the core cannot time are refused with what they must be.
    #[test]
    fn bad_arguments_are_refused_by_name() {
        let model = cluttered_arm();
        let path = [0.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0];
        let err = |r: Result<Timed>| r.unwrap_err().to_string();
        assert!(err(time_path(&model, &path[..4], &[1.0; 4], &[1.0; 4], true, 0.5, 1e-6)).contains("two waypoints"));
        assert!(err(time_path(&model, &path, &[1.0, 1.0, 0.0, 1.0], &[1.0; 4], true, 0.5, 1e-6)).contains("velocity"));
        assert!(err(time_path(&model, &path, &[1.0; 4], &[1.0; 3], true, 0.5, 1e-6)).contains("acceleration"));
        assert!(err(time_path(&model, &path, &[1.0; 4], &[1.0; 4], true, 0.7, 1e-6)).contains("cut"));
        assert!(err(time_path(&model, &[0.0; 8], &[1.0; 4], &[1.0; 4], true, 0.5, 1e-6)).contains("zero-length"));
    }
}
