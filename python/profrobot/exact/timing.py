"""Timed paths: a waypoint path in time, within each joint's velocity and acceleration limits,
its geometry certified.

:func:`time_path` turns a path ((M, K) waypoints, as :func:`profrobot.plan_path` returns) into a
:class:`TimedPath`: positions, velocities and accelerations at any time, at a controller's rate.
The path's straight segments are crossed at constant velocity and each corner is rounded by a
**parabolic blend** (constant acceleration), so the robot does not stop at every waypoint; a
blend leaves the path, so each one is **proven free** by the continuous certificate
(:func:`profrobot.certify_motions` with ``via=``), and one that is not becomes a stop.

**Corner cuts.** A parabolic blend takes exactly the time the cruise it replaces would (its
velocity goes from one segment's to the next's), so blends alone save only the stops; with each
joint at its own velocity limit, a straight chord across a corner is quicker than the two
half-segments it replaces (``max_j |x_j + y_j|/v_j ≤ max_j |x_j|/v_j + max_j |y_j|/v_j``, and
strictly less where different joints lead the two segments). So first (step 0), with ``cut`` > 0:
corner ``i`` is cut by the chord from ``W_i − D_{i−1}·c`` to ``W_i + D_i·c`` (points of the two
segments, ``c`` a share of each), the widest of ``cut``, ``cut/2``, ``cut/4`` whose chord the
continuous certificate proves free, none where no chord is. The chord's ends become waypoints
and steps 1–3 time the cut path, its blends proven as below; the parts of the path's segments
it still crosses, between the chords, are proven too (none where two chords of half a segment
meet at its middle), and only those: a segment the chords bypass need not be free. The cut
timing is kept unless the path uncut is faster (computed only when its best case, every blend
proven, could be) or certified where the cut one is not. ``cut=0`` times the path's own
corners.

**The math.** Per run of waypoints ``W_0 … W_n`` between two stops (at rest at both ends),
``D_i = W_{i+1} − W_i`` (short arcs on continuous hinges), joint limits ``v_j`` (rad/s or m/s)
and ``a_j`` (rad/s² or m/s²):

1. Segment ``i`` is crossed at the constant velocity ``V_i = D_i / T_i``, with
   ``T_i ≥ max_j |D_ij| / v_j`` (no joint above its velocity limit).
2. At waypoint ``i`` the velocity changes from ``V_{i−1}`` to ``V_i`` (``V_{−1} = V_n = 0``)
   at constant acceleration ``A_i = (V_i − V_{i−1}) / τ_i`` over
   ``τ_i = max_j |V_ij − V_{i−1,j}| / a_j``, centred on the waypoint's time ``t_i``:
   ``q(t_i − τ_i/2 + s) = W_i − V_{i−1}·τ_i/2 + V_{i−1}·s + A_i·s²/2``, ``s ∈ [0, τ_i]``.
   That is the quadratic Bézier ``W_i − V_{i−1}τ_i/2 → W_i → W_i + V_iτ_i/2``; at a run's
   ends it is a straight start or stop along the segment.
3. A segment must hold half of each blend: ``τ_i/2 + τ_{i+1}/2 ≤ T_i``. The speeds start from a
   ramp (forward and backward passes that fit each blend in half of each neighbour, so that
   many short segments speed up and slow down across several of them) and from every
   segment at its velocity limit, the shorter result kept; a segment where the blends still
   do not fit is slowed (``T_i ← T_i·√(need / T_i)``, the exact answer for a lone segment)
   until they do; after 200 rounds a run still infeasible stops at every waypoint (each
   segment alone needs ``T_i = max(max_j |D_ij|/v_j, √(max_j |D_ij|/a_j))``).

So velocity is piecewise linear between the ``V_i`` and acceleration piecewise constant, each
within its limit by construction (checked again by the tests at 1 kHz). The cruise parts lie on
the path's segments and the chords; what the robot crosses of them and every blend are
certified continuously (``margin`` metres from every obstacle, :data:`~profrobot.CLEARANCE` at
least); a blend that is not proven becomes a stop at its waypoint (the robot reaches it at
rest, along the segments, and the run on either side is timed again), until every blend left
is proven. ``certified`` then holds for the whole timed motion exactly when every part of the
path it crosses is proven. Without ``jerk``, acceleration
steps at the ends of each blend. Steps 0–3 and their proofs run in the core
(``rust/planning/timing.rs``), with the call's ``threads``.

**With a jerk limit** ``j_j`` (rad/s³ or m/s³) the robot stops at every waypoint, on the
path's segments exactly: a blend at speed must have continuous curvature to keep jerk finite,
and such a curve is not one the certificate proves (it proves segments and quadratic blends).
Each segment is one rest-to-rest move of ``s ∈ [0, 1]``, ``q = W_i + D_i·s``, within
``v_s = min_j v_j/|D_ij|``, ``a_s = min_j a_j/|D_ij|`` and ``j_s = min_j j_j/|D_ij|`` (so each
joint is within its own limits, and every joint moves in phase, as Ruckig's phase
synchronisation does): the time-optimal double-S profile (Biagiotti & Melchiorri, *Trajectory
Planning for Automatic Machines and Robots*, §3.4). The acceleration phase to a peak speed
``u`` is a jerk ramp ``t_j``, a constant-acceleration part ``t_c`` and a ramp down, with
``t_j = a_s/j_s``, ``t_c = u/a_s − t_j`` when ``u·j_s ≥ a_s²`` (the acceleration limit is
reached), else ``t_j = √(u/j_s)``, ``t_c = 0``; by symmetry it covers ``u·(2t_j + t_c)/2``.
``u = v_s`` when acceleration and deceleration together cover at most 1 (the rest is cruise),
else the peak solves ``u·(2t_j + t_c) = 1``: ``u = a_s(−a_s/j_s + √(a_s²/j_s² + 4/a_s))/2``
when that reaches the acceleration limit, else ``u = (√j_s / 2)^{2/3}``. Pieces are then of
constant jerk.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from .._core import crew_awake
from ..errors import CorruptFileError, InputError, MissingFileError
from .certification import CLEARANCE, certify_motions
from .labels import as_poses, check_threads, so2_steps
from ..files import atomic_path, check_format, check_robot, format_tag
from ..robot import gate
from ..robot.gate import Layout
from ..robot.robot import Robot

__all__ = ["TimedPath", "time_path"]

_FORMAT = "profrobot-timed-path"
_VERSION = 2   # 2: pieces of constant jerk (jrk) and the jerk limit


@dataclass
class TimedPath:
    """A path in time (:func:`time_path`): pieces of constant jerk (zero without a jerk limit).

    Piece ``p`` holds from ``starts[p]`` (s) to the next start (or ``duration``):
    ``q(t) = q0[p] + v0[p]·τ + acc[p]·τ²/2 + jrk[p]·τ³/6`` with ``τ = t − starts[p]``, in
    unwrapped joint coordinates (continuous hinges are wrapped into [-π, π) by :meth:`sample`).

    Attributes:
        duration: seconds from the first waypoint, at rest, to the last, at rest.
        starts: (P,) seconds, each piece's start (the first is 0).
        q0, v0, acc: (P, K) position (rad / m), velocity (per s) and acceleration (per s²) at
            each piece's start.
        jrk: (P, K) each piece's constant jerk (per s³; zero without a jerk limit).
        times: (M,) seconds at which the robot is at each stop, or the blend around a corner
            is half done (there it is at ``W_i + (V_i − V_{i−1})·τ_i/8``, off the corner), for
            each of ``waypoints``.
        stops: (M,) bool, the waypoints the robot reaches at rest: the ends, and every corner
            whose blend was not proven (or with ``blend=False``).
        waypoints: (M, K) the path timed: the one given, zero-length segments removed, each
            corner cut (``time_path(cut=)``) replaced by the two ends of its chord.
        velocity, acceleration, jerk: (K,) the limits it was timed within (``jerk`` is inf
            where there was none).
        certified: every pose of the timed motion is certified free (the parts of the path's
            segments it crosses, every chord and every blend kept,
            :mod:`profrobot.exact.certification`).
        reason: why not certified ('' when it is).
        wraps: (K,) bool, the continuous hinges.
        robot_name, robot_fingerprint, joint_names: the robot it was timed for.
    """

    duration: float
    starts: np.ndarray
    q0: np.ndarray
    v0: np.ndarray
    acc: np.ndarray
    jrk: np.ndarray
    times: np.ndarray
    stops: np.ndarray
    waypoints: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray
    certified: bool
    reason: str
    wraps: np.ndarray
    robot_name: str = ""
    robot_fingerprint: str = ""
    joint_names: list[str] = field(default_factory=list)

    def sample(self, t: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities and accelerations at times ``t`` (seconds; a number or (T,),
        clamped to [0, duration]): ``(q, qd, qdd)``, each (T, K) (or (K,) for a number);
        continuous hinges wrapped into [-π, π). At a piece's boundary the later piece's
        acceleration is given."""
        tt = np.asarray(t, dtype=np.float64)
        one = tt.ndim == 0
        tt = np.atleast_1d(tt)
        if tt.ndim != 1 or not np.isfinite(tt).all():
            raise InputError(f"t must be a finite number or (T,) finite seconds; got shape {np.shape(t)}")
        tt = np.clip(tt, 0.0, self.duration)
        p = np.clip(np.searchsorted(self.starts, tt, side="right") - 1, 0, len(self.starts) - 1)
        tau = (tt - self.starts[p])[:, None]
        q = self.q0[p] + tau * (self.v0[p] + tau * (0.5 * self.acc[p] + tau * self.jrk[p] / 6))
        qd = self.v0[p] + tau * (self.acc[p] + 0.5 * tau * self.jrk[p])
        qdd = self.acc[p] + tau * self.jrk[p]
        q[:, self.wraps] = (q[:, self.wraps] + np.pi) % (2 * np.pi) - np.pi
        return (q[0], qd[0], qdd[0]) if one else (q, qd, qdd)

    def at_rate(self, hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t, q, qd, qdd)`` every ``1/hz`` seconds from 0, the end included (a controller's
        stream): t (T,) seconds, the rest (T, K)."""
        hz = gate.positive("hz", hz)
        n = int(np.floor(self.duration * hz + 1e-9)) + 1
        t = np.arange(n) / hz
        if t[-1] < self.duration:
            t = np.append(t, self.duration)
        return (t, *self.sample(t))

    def summary(self) -> str:
        corners = len(self.stops) - 2
        stopped = int(self.stops[1:-1].sum()) if corners > 0 else 0
        proof = "certified free" if self.certified else f"NOT certified ({self.reason})"
        return (f"{self.duration:.3f} s over {len(self.waypoints)} waypoints, {max(corners, 0) - stopped} "
                f"blended corners, {stopped} stops; {proof}")

    def save(self, path: str | os.PathLike) -> Path:
        """Write to ``path`` (.npz, atomically); :meth:`load` reads it."""
        path = Path(path)
        meta = dict(format=format_tag(_FORMAT, _VERSION), robot=self.robot_name,
                    robot_fingerprint=self.robot_fingerprint, joint_names=self.joint_names,
                    duration=self.duration, certified=self.certified, reason=self.reason)
        with atomic_path(path, ".npz") as tmp:
            np.savez(tmp, starts=self.starts, q0=self.q0, v0=self.v0, acc=self.acc, jrk=self.jrk, times=self.times,
                     stops=self.stops, waypoints=self.waypoints, velocity=self.velocity,
                     acceleration=self.acceleration, jerk=self.jerk, wraps=self.wraps,
                     meta=np.array(json.dumps(meta)))
        return path

    @classmethod
    def load(cls, path: str | os.PathLike, robot: Robot | None = None) -> "TimedPath":
        """Read a file :meth:`save` wrote; with ``robot``, refuse one timed for another robot."""
        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"no timed path at {path}")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            meta = json.loads(str(arrays.pop("meta")))
        except (OSError, ValueError, KeyError) as e:
            raise CorruptFileError(f"{path} is not a timed path: {e}") from None
        check_format(meta.get("format"), _FORMAT, _VERSION, str(path))
        if robot is not None:
            check_robot(meta, robot, f"timed path {str(path)!r}")
        return cls(duration=float(meta["duration"]), certified=bool(meta["certified"]), reason=str(meta["reason"]),
                   robot_name=str(meta["robot"]), robot_fingerprint=str(meta["robot_fingerprint"]),
                   joint_names=list(meta["joint_names"]), **arrays)


def _double_s(v: float, a: float, j: float) -> list[tuple[float, float]]:
    """The time-optimal rest-to-rest move of ``s`` from 0 to 1 within speed ``v``, acceleration
    ``a`` and jerk ``j`` (module docs): its phases ``(duration, jerk)``, zero-length ones left out."""

    def ramp(u: float) -> tuple[float, float]:      # (t_j, t_c) of the acceleration to speed u
        if u * j >= a * a:
            return a / j, max(u / a - a / j, 0.0)
        return float(np.sqrt(u / j)), 0.0

    tj, tc = ramp(v)
    cruise = (1.0 - v * (2 * tj + tc)) / v
    if cruise < 0:
        u = a * (-a / j + np.sqrt(a * a / (j * j) + 4 / a)) / 2
        if u * j < a * a:
            u = (np.sqrt(j) / 2) ** (2 / 3)
        (tj, tc), cruise = ramp(float(u)), 0.0
    phases = [(tj, j), (tc, 0.0), (tj, -j), (cruise, 0.0), (tj, -j), (tc, 0.0), (tj, j)]
    return [(t, jj) for t, jj in phases if t > 0]


def _jerk_pieces(w: np.ndarray, v: np.ndarray, a: np.ndarray, jerk: np.ndarray):
    """Stops at every waypoint, each segment a double-S move (module docs): the pieces
    (starts, (q0, v0, acc, jrk)), the duration and the waypoints' times."""
    starts, q0, v0, acc, jrk = [], [], [], [], []
    times = np.zeros(len(w))
    clock = 0.0
    for i, d in enumerate(np.diff(w, axis=0)):
        ad = np.abs(d)
        moving = ad > 0
        lim = [float((x[moving] / ad[moving]).min()) for x in (v, a, jerk)]
        s = sd = sdd = 0.0
        for h, jj in _double_s(*lim):
            starts.append(clock)
            q0.append(w[i] + d * s)
            v0.append(d * sd)
            acc.append(d * sdd)
            jrk.append(d * jj)
            s += h * (sd + h * (sdd / 2 + h * jj / 6))
            sd += h * (sdd + h * jj / 2)
            sdd += h * jj
            clock += h
        times[i + 1] = clock
    return np.asarray(starts), tuple(map(np.asarray, (q0, v0, acc, jrk))), clock, times


def time_path(robot: Robot, path: npt.ArrayLike, *, velocity: npt.ArrayLike | float | None = None,
              acceleration: npt.ArrayLike | float | None = None, jerk: npt.ArrayLike | float | None = None,
              blend: bool = True, cut: float = 0.5,
              layout: Layout | None = None, margin: float = CLEARANCE, threads: int | None = None) -> TimedPath:
    """Time ``path`` ((M, K) waypoints, radians / metres; as :func:`profrobot.plan_path`
    returns) within each joint's ``velocity`` (rad/s or m/s) and ``acceleration`` (rad/s² or
    m/s²) limits, each a number (every joint) or (K,); both required (MJCF carries no such
    limits) and refused by name when not positive and finite.

    The robot starts and ends at rest; with ``blend`` (the default) it rounds each corner with
    a parabolic blend proven free, and stops at the corners whose blend is not (module docs);
    with ``blend=False`` it stops at every waypoint, on the path exactly. ``cut`` (a share of
    each segment, in [0, 0.5]; with blends and no jerk limit): each corner is first cut by a
    straight chord between points this share (or a half, or a quarter of it) of the way along
    the segments beside it, where the chord is proven free and the cut path is quicker (module
    docs); the chords' ends are then among ``waypoints``. 0 keeps the path's own corners (a
    straight-line move of :func:`profrobot.plan_cartesian`, whose frame would leave its line).
    ``margin`` and ``layout`` as for :func:`profrobot.plan_path` (the path and the blends keep ``margin``).
    ``certified`` says whether every pose of the timed motion is proven free; a path with a
    segment that is not, where the timed motion crosses it, is timed all the same, with
    ``certified=False`` and the reason (a segment the corner cuts bypass need not be free).
    The segments of a path ``plan_path`` returned on this robot are proven already: the parts of
    the timed motion on them are not proven again (the timing is the same either way).
    """
    threads = check_threads(threads)
    # (the native call's helper threads woken now, so that they are awake when its first
    # section starts: woken inside it, one started 24 µs late, 2 % of a 20-waypoint call;
    # the guard let go on the way out, also where an exception's traceback keeps the frame)
    awake = crew_awake(threads)
    try:
        return _timed(robot, path, velocity, acceleration, jerk, blend, cut, layout, margin, threads)
    finally:
        del awake


def _timed(robot: Robot, path: npt.ArrayLike, velocity: npt.ArrayLike | float | None,
           acceleration: npt.ArrayLike | float | None, jerk: npt.ArrayLike | float | None, blend: bool,
           cut: float, layout: Layout | None, margin: float, threads: int | None) -> TimedPath:
    """:func:`time_path` past its thread count (checked, the crew woken)."""
    robot = gate.robot_at(robot, layout=layout, margin=margin)
    p = as_poses(robot, path, name="path", check_limits=True)
    if len(p) < 1:
        raise InputError("path must hold at least one waypoint")
    v = gate.per_joint(robot, "velocity", velocity, "rad/s or m/s")
    a = gate.per_joint(robot, "acceleration", acceleration, "rad/s² or m/s²")
    j = np.full(robot.njoint, np.inf) if jerk is None else gate.per_joint(robot, "jerk", jerk, "rad/s³ or m/s³")
    if not isinstance(blend, (bool, np.bool_)):
        raise InputError(f"blend must be True or False; got {blend!r}")
    cut = gate.positive("cut", cut, allow_zero=True)
    if cut > 0.5:
        raise InputError(f"cut must be a share of each segment in [0, 0.5]; got {cut!r}")
    if robot.couplings and not robot.couplings.linear:
        raise InputError(f"{robot.name} has nonlinear joint couplings: a timed path would leave them between "
                         "waypoints (time_path handles linear couplings)")
    # Unwrapped waypoints (short arcs on continuous hinges; the other joints' values as given, bit
    # for bit, so that a planned path's segments are the motions plan_path proved), zero-length
    # segments removed.
    # (a handful of small numpy calls, and Python lists where a row is a handful of numbers:
    # each numpy call costs microseconds, several times that right after the native work has
    # evicted numpy's ufunc and reduction machinery from the caches, and this runs on every call)
    w = p.copy()
    wraps = np.asarray(robot.continuous, dtype=bool)
    if len(p) > 1 and True in wraps.tolist():
        steps = so2_steps(robot, p)
        w[1:, wraps] = p[0, wraps] + np.cumsum(steps[:, wraps], axis=0)
    # (read on the unwrapped waypoints: a step below their rounding leaves two of them equal;
    # finite values differ exactly where their difference is not 0, as Python's floats compare)
    rows = w.tolist()
    kept = [0] + [i for i in range(1, len(rows)) if rows[i] != rows[i - 1]]
    if len(kept) < len(rows):
        w = w[kept]
    m = len(w)
    meta = dict(robot_name=robot.name, robot_fingerprint=robot.fingerprint, joint_names=list(robot.joint_names),
                wraps=wraps, velocity=v, acceleration=a, jerk=j, waypoints=w)
    if m == 1:
        free = bool(certify_motions(robot, w, w, threads=threads).certified[0])
        return TimedPath(duration=0.0, starts=np.zeros(1), q0=w.copy(), v0=np.zeros_like(w), acc=np.zeros_like(w),
                         jrk=np.zeros_like(w), times=np.zeros(1), stops=np.ones(1, bool), certified=free,
                         reason="" if free else "the pose is not certified free", **meta)
    if jerk is None:
        out = robot.core.time_path(w, v, a, CLEARANCE, blend=bool(blend), cut=float(cut), threads=threads)
        starts, q0, v0, acc = out["starts"], out["q0"], out["v0"], out["acc"]
        duration, times, stops = out["duration"], out["times"], out["stops"]
        bad, verdict = out["unproven_segment"], out["unproven_verdict"]
        meta["waypoints"] = out["waypoints"]
        jrk = np.zeros(q0.shape)
    else:
        verdicts = robot.core.certify_motions(w[:-1], w[1:], CLEARANCE, as_given=True, threads=threads)["verdict"]
        failed = np.flatnonzero(verdicts != 0)
        bad, verdict = (int(failed[0]), int(verdicts[failed[0]])) if len(failed) else (-1, 0)
        starts, (q0, v0, acc, jrk), duration, times = _jerk_pieces(w, v, a, j)
        stops = np.ones(m, dtype=bool)
    reason = "" if bad < 0 else (
        f"segment {bad} of the path given (its waypoints {bad} → {bad + 1}) is "
        f"{'blocked' if verdict == 1 else 'not proven free'} where the timed motion crosses it; "
        "time a certified path (plan_path)")
    return TimedPath(duration=float(duration), starts=starts, q0=q0, v0=v0, acc=acc, jrk=jrk, times=times, stops=stops,
                     certified=bad < 0, reason=reason, **meta)
