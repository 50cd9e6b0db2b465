"""Straight-line moves of a frame: the approach and the retreat of a grasp, certified.

:func:`plan_cartesian` moves a frame (a site, body or geom, with an optional tool offset) along
straight lines between given poses: position linear, orientation by slerp (held where the
targets are positions only). It returns a joint path whose every pose keeps the frame within
``position_tolerance`` metres and ``rotation_tolerance`` radians of the line, and whose every
segment is certified free continuously; where the line cannot be followed, the part that can,
the fraction of the line it covers and why the rest cannot (as MoveIt's
``computeCartesianPath`` does), never a path that leaves the line or is not proven.

**How.** The line is cut into waypoints at most ``step`` metres (and ``10·step`` radians) apart;
certified IK (:func:`profrobot.ik`, one seed: the previous joint pose) solves them all at once
from the start, then again from the last good pose wherever the solutions stop following
the line. Between consecutive joint waypoints the motion is the straight joint interpolation;
the frame's deviation from the line there is bounded everywhere on it, not only where it is
sampled: forward kinematics at a few samples, spaced by the joints' motion, and a bound on how
far the frame can move off the chord between two samples and turn between them (``_bounded``,
its exactness argument there; a flip of the elbow between two nearby frame poses moves the
joints far, and its bound takes it). Where the frame's chain has a slide or coupled joint the
deviation is sampled instead, every 0.1 mm of the frame's travel and every 0.2 mrad of the
joints'. A segment that strays is solved again
from its start pose (the rest of the line with it: the batch may have chosen another branch),
then halved (a new waypoint in the middle, solved from the segment's start) up to 6 times, at
most twice as many waypoints added in all as the line had. The joint path is then certified by the continuous
certificate (:func:`profrobot.certify_motions`) and cut at the first segment not proven free.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from .certification import CLEARANCE, certify_motions, certify_poses
from .ik import IKResult, as_targets, frame_of, ik, with_tool
from .labels import as_poses, check_threads, label_poses
from ..robot import gate
from ..robot.gate import Layout
from ..robot.robot import Robot

__all__ = ["CartesianPath", "plan_cartesian"]

#: metres of the frame's travel between two deviation checks (from the segment's ends), and
#: radians of the joints' (a segment whose ends are close in space may still swing far between
#: them: an arm flipping its elbow between two nearby frame poses)
CHECK_SPACING = 1e-4
JOINT_SPACING = 2e-4
_HALVINGS = 6


@dataclass
class CartesianPath:
    """A straight-line move of a frame (:func:`plan_cartesian`).

    Attributes:
        path: (M, K) joint waypoints from the start (radians / metres); every segment certified
            free and keeping the frame on the line.
        fraction: the share of the line's length (metres; radians where it only turns) the
            path covers, in [0, 1].
        reached: ``fraction == 1``: the whole line is followed.
        reason: why the line stops where it does ('' when reached).
        position_deviation: metres, a bound on the frame's distance from the line anywhere on
            the path (module docs; the largest found every 0.1 mm of its travel where its chain
            has a slide or coupled joint); rotation_deviation: radians, likewise from the slerp.
        seconds: wall time.
    """

    path: np.ndarray
    fraction: float
    reached: bool
    reason: str
    position_deviation: float
    rotation_deviation: float
    seconds: float

    def summary(self) -> str:
        state = "the whole line" if self.reached else f"{self.fraction:.1%} of the line ({self.reason})"
        return (f"{state}: {len(self.path)} waypoints, frame within {self.position_deviation * 1e3:.3f} mm and "
                f"{self.rotation_deviation * 1e3:.2f} mrad of it, every segment certified; "
                f"{self.seconds * 1e3:.1f} ms")


# (the quaternion arithmetic in numpy, (w, x, y, z): scipy's Rotation costs ~0.1 ms a call on these
# small batches, which was most of a move's time)
def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of (N, 4) and (N, 4) or (4,) quaternions, (w, x, y, z)."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3): the vector ``v`` (3,) rotated by each unit quaternion of ``q`` (N, 4):
    ``v + w t + u × t`` with ``t = 2 u × v`` (``u`` the vector part), written out by component."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    vx, vy, vz = (float(c) for c in v)
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    out = np.empty((len(q), 3))
    out[:, 0] = vx + w * tx + y * tz - z * ty
    out[:, 1] = vy + w * ty + z * tx - x * tz
    out[:, 2] = vz + w * tz + x * ty - y * tx
    return out


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Radians between unit quaternions, row by row."""
    return 2.0 * np.arccos(np.clip(np.abs((a * b).sum(axis=-1)), 0.0, 1.0))


def _slerp(qa: np.ndarray, qb: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions from ``qa`` to ``qb`` (4,) each at ``u`` (N,), the short way."""
    if qa @ qb < 0:
        qb = -qb
    c = float(np.clip(qa @ qb, -1.0, 1.0))
    th = np.arccos(c)
    if th < 1e-9:
        return np.broadcast_to(qa, (len(u), 4)).copy()
    sa, sb = np.sin((1 - u) * th) / np.sin(th), np.sin(u * th) / np.sin(th)
    return sa[:, None] * qa + sb[:, None] * qb


def _matrices(q: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of unit quaternions ``q`` (N, 4), (w, x, y, z)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    m = np.empty((len(q), 3, 3))
    m[:, 0, 0], m[:, 0, 1], m[:, 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    m[:, 1, 0], m[:, 1, 1], m[:, 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    m[:, 2, 0], m[:, 2, 1], m[:, 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return m


class _Line:
    """The polyline of legs between frame poses: points, rotations and arc length."""

    def __init__(self, pos: np.ndarray, quats: np.ndarray, step: float):
        lengths = np.linalg.norm(np.diff(pos, axis=0), axis=1)
        if (lengths <= 1e-12).any():
            # (a leg that only turns, given as a target whose position is the start's to the last
            # bits, as MuJoCo's and the core's forward kinematics differ: of length zero, so that
            # it is measured by its angle, not along a chord of 1e-16 m)
            pos = pos.copy()
            for i in np.flatnonzero(lengths <= 1e-12):
                pos[i + 1] = pos[i]
            lengths = np.where(lengths <= 1e-12, 0.0, lengths)
        self.pos = pos
        quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
        # (the turn of each leg: 2 atan2(|v|, |w|) of the relative rotation, exact also where small)
        rel = _qmul(quats[:-1] * [1.0, -1.0, -1.0, -1.0], quats[1:])
        angles = 2.0 * np.arctan2(np.linalg.norm(rel[:, 1:], axis=1), np.abs(rel[:, 0]))
        self.turning_only = lengths.sum() <= 1e-12
        self.chord, self.turn = lengths, angles
        self.length = angles if self.turning_only else lengths
        self.total = float(self.length.sum())
        self.quats = quats
        self.cuts = [max(1, int(np.ceil(max(lengths[i] / step, angles[i] / (10 * step))))) for i in range(len(pos) - 1)]

    def at(self, leg: int, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3) and rotation matrices (N, 3, 3) on leg ``leg`` at ``u`` (N,): the
        deviation's own slerp (``_slerp``), so the targets are the line it measures from."""
        q = _slerp(self.quats[leg], self.quats[leg + 1], np.asarray(u, dtype=np.float64))
        return self.pos[leg] + np.outer(u, self.pos[leg + 1] - self.pos[leg]), _matrices(q)

    def deviation(self, leg: int, p: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distance to the leg's segment, angle to its slerp at the nearest point, that point's
        u) of frame positions ``p`` (N, 3) and orientations ``r`` (N, 4) (w, x, y, z)."""
        a, b = self.pos[leg], self.pos[leg + 1]
        qa, qb = self.quats[leg], self.quats[leg + 1]
        d = b - a
        dd = float(d @ d)
        if dd > 0:
            u = np.clip((p - a) @ d / dd, 0.0, 1.0)
        else:   # (a turn in place: the parameter from the rotation)
            total = float(_angle(qa, qb))
            u = np.clip(_angle(np.broadcast_to(qa, r.shape), r) / total, 0.0, 1.0) if total > 0 else np.zeros(len(p))
        dist = np.linalg.norm(a + np.outer(u, d) - p, axis=1)
        return dist, _angle(_slerp(qa, qb, u), r), u

    def deviations(self, legs: np.ndarray, p: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``deviation``'s distances and angles of frames ``p`` (N, 3), ``r`` (N, 4), each from
        its own leg ``legs`` (N,)."""
        dist, ang = np.zeros(len(legs)), np.zeros(len(legs))
        for leg in np.unique(legs):
            on = legs == leg
            dist[on], ang[on], _ = self.deviation(int(leg), p[on], r[on])
        return dist, ang


def _largest(n: int, seg: np.ndarray, *values: np.ndarray) -> list[np.ndarray]:
    """Per segment 0..n-1, the largest of each of ``values`` over the entries ``seg`` names it in
    (0 for a segment named nowhere)."""
    out = []
    for v in values:
        m = np.zeros(n)
        np.maximum.at(m, seg, v)
        out.append(m)
    return out


#: the most intervals one segment's bound is cut into (a joint flip between two nearby frame poses
#: would need more: that segment is then not shown on the line, and is halved as one that strays)
_MOST_INTERVALS = 4096


def _lever_arms(robot: Robot, body: int, lpos: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The joints that move the frame point ``lpos`` of ``body``, base to tip, and for each a bound
    ρ_j (metres) on the point's distance from the joint's anchor at every pose; None where one of
    them is a slide or a coupled joint (the sampled check serves those).

    Exactness: the anchor of hinge j keeps its distance ``|anchor_j|`` from its body's origin;
    each later hinge of that body moves the origin by at most ``2 |anchor_k|`` (it turns the
    anchor's offset about its own anchor); from a body's origin to its child's is ``|pos|`` and
    to the frame point ``|lpos|``. ρ_j is the sum along the chain (the triangle inequality)."""
    parent, jbody, jtype = robot.body_parents.tolist(), robot.joint_bodies.tolist(), robot.joint_types
    arm = np.linalg.norm(robot.joint_anchors, axis=1).tolist()
    offset = np.linalg.norm(robot.body_offsets, axis=1).tolist()
    dependent = set(robot.couplings.dependent)
    on_body: dict[int, list[int]] = {}
    for j, b in enumerate(jbody):
        on_body.setdefault(b, []).append(j)
    joints: list[int] = []
    rho: list[float] = []
    after = float(np.linalg.norm(lpos))          # bounds |origin of body b - the point|
    b = int(body)
    while b > 0:                                   # (tip to base)
        js = on_body.get(b, [])
        if any(jtype[j] != "hinge" or j in dependent for j in js):
            return None
        later = 0.0
        for j in reversed(js):
            joints.append(j)
            rho.append(arm[j] + later + after)
            later += 2 * arm[j]
        after += later + offset[b]
        b = parent[b]
    return np.array(joints[::-1], dtype=np.int64), np.array(rho[::-1])


def _bounded(line: _Line, frames, q: np.ndarray, d: np.ndarray, seg_legs: np.ndarray,
             arms: tuple[np.ndarray, np.ndarray], tols: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Upper bounds (metres, radians) on the frame's distance from leg ``seg_legs[i]`` and angle
    from its slerp anywhere on each joint segment ``q[i] + s d[i]``, s in [0, 1], from the frame
    at a few samples each.

    Exactness, on a chain of hinges (``_lever_arms``), s the segment's parameter: the frame point
    moves at ``|p'| ≤ Σ |d_j| ρ_j`` and turns at ``|ω| ≤ Σ |d_j|`` (unit axes); differentiating
    ``p' = Σ d_j ω_j × (p - a_j)`` once more (``ω_j' = Σ_{i<j} d_i ω_i × ω_j``, the anchors moved
    by the joints before them) gives ``|p''| ≤ Σ_j |d_j| (2 D_j ρ_j + Σ_{i≥j} |d_i| ρ_i)``, D_j
    = ``Σ_{i<j} |d_i|``. Between two samples h apart the point is within ``h² max|p''| / 8`` of
    the chord between them, and the chord's distance from the leg (a convex set) is at most the
    larger of its ends': the position bound. The angle to the slerp is Lipschitz with ``|ω|``
    plus the slerp's rate (θ_leg per unit u, and u moves at most ``|p'| / |leg|``; a leg that only
    turns takes u from the angle, at most ``|ω| / θ``), so between samples it is at most the mean
    of the ends' plus half the rate times h. Samples are spaced so that these terms are half the
    tolerance and the rate times h the tolerance; a segment not shown within the tolerances is
    sampled four times finer, twice (each round's bound holds: the least is kept), and is
    otherwise reported with its bound (it strays). The measured angles carry arccos's rounding
    near zero, ~1e-8 rad. A leg that mostly turns (millimetres of travel, a large turn) takes
    many samples: its slerp's rate per metre of the frame's travel is large."""
    joints, rho = arms
    tol_p, tol_r = tols
    dj = np.abs(d[:, joints])
    lp = dj @ rho
    lr = dj.sum(axis=1)
    before = np.cumsum(dj, axis=1) - dj
    tail = np.cumsum((dj * rho)[:, ::-1], axis=1)[:, ::-1]
    m2 = (dj * (2 * before * rho + tail)).sum(axis=1)
    chord, turn = line.chord[seg_legs], line.turn[seg_legs]
    la = lr + np.where(chord > 0, turn * lp / np.where(chord > 0, chord, 1.0), lr)
    k = np.ceil(np.maximum(np.sqrt(m2 / (4 * tol_p)), la / tol_r))
    k = np.clip(np.nan_to_num(k, nan=_MOST_INTERVALS), 1, _MOST_INTERVALS).astype(np.int64)
    out_d, out_a = np.full(len(d), np.inf), np.full(len(d), np.inf)
    todo = np.arange(len(d))
    for _ in range(3):
        kt = k[todo]
        seg = np.repeat(todo, kt + 1)
        first = np.concatenate([[0], np.cumsum(kt + 1)[:-1]])
        s = (np.arange(len(seg)) - np.repeat(first, kt + 1)) / np.repeat(kt, kt + 1)
        dist, ang = line.deviations(seg_legs[seg], *frames(q[seg] + s[:, None] * d[seg]))
        left = np.flatnonzero(seg[:-1] == seg[1:])            # intervals [left, left + 1]
        iseg, h = seg[left], 1.0 / k[seg[left]]
        pos = np.maximum(dist[left], dist[left + 1]) + h * h * m2[iseg] / 8
        rot = np.maximum(np.maximum(ang[left], ang[left + 1]), (ang[left] + ang[left + 1] + la[iseg] * h) / 2)
        bd, ba = _largest(len(d), iseg, pos, rot)
        out_d[todo], out_a[todo] = np.minimum(out_d[todo], bd[todo]), np.minimum(out_a[todo], ba[todo])
        # (finer samples can only help where the samples themselves are within the tolerances)
        sd, sa = _largest(len(d), seg, dist, ang)
        fail = todo[((out_d[todo] > tol_p) | (out_a[todo] > tol_r)) & (sd[todo] <= tol_p) & (sa[todo] <= tol_r)
                    & (k[todo] < _MOST_INTERVALS)]
        if not len(fail):
            break
        k[fail] = np.minimum(4 * k[fail], _MOST_INTERVALS)
        todo = fail
    return out_d, out_a


def plan_cartesian(robot: Robot, start: npt.ArrayLike, targets: npt.ArrayLike, *, frame: str,
                   tool: npt.ArrayLike | None = None, step: float = 0.005, position_tolerance: float = 1e-3,
                   rotation_tolerance: float = 0.01, locked: Sequence[str] = (), layout: Layout | None = None,
                   margin: float = CLEARANCE, threads: int | None = None) -> CartesianPath:
    """Move ``frame`` from where it is at ``start`` ((K,), a certified pose) along straight lines
    through ``targets`` (as in :func:`profrobot.ik`: (N, 4, 4) world transforms, or (N, 3)
    positions in metres with the start's orientation held), position linear and orientation by
    slerp, the frame within ``position_tolerance`` (m) and ``rotation_tolerance`` (rad) of the
    line at every pose (module docs). ``tool``: a (3,) offset or (4, 4) transform of the tool in
    the frame's coordinates (the targets are the tool's poses). ``step``: metres between the
    waypoints solved (10·step radians of turning). ``locked``: joints that keep their start
    values; joints that do not move the frame keep them too. ``layout``, ``margin``: as for
    :func:`profrobot.plan_path`.

    Returns a :class:`CartesianPath`: the certified joint path along as much of the line as can
    be followed, the fraction it covers and why it stops (a joint limit or singularity, a
    collision, a segment the certificate does not prove)."""
    t0 = time.perf_counter()
    robot = gate.robot_at(robot, layout=layout, margin=margin)
    s = as_poses(robot, start, name="start", check_limits=True)
    if s.shape != (1, robot.njoint):
        raise InputError(f"start must be one pose of {robot.njoint} joints; got shape {np.shape(start)}")
    step = gate.positive("step", step)
    position_tolerance = gate.positive("position_tolerance", position_tolerance)
    rotation_tolerance = gate.positive("rotation_tolerance", rotation_tolerance)
    threads = check_threads(threads)
    body, lpos, lquat = frame_of(robot, frame)
    lpos, lquat = with_tool(lpos, lquat, tool)
    gate.joint_mask(robot, locked, "locked")
    if not certify_poses(robot, s)[0]:
        lab = label_poses(robot, s, pairs=True)
        why = (f"collides ({' / '.join(robot.pair_names(int(lab.colliding_pairs[0, 1])))})"
               if lab.collides[0] and lab.colliding_pairs is not None and len(lab.colliding_pairs)
               else "is within the clearance of contact or off its couplings")
        raise InputError(f"start {why}; move from a certified pose")

    def frames(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the frame is at poses ``q`` (N, K): positions (N, 3), quaternions (N, 4) (w, x, y, z)."""
        xb, qb = robot.core.body_frames(np.ascontiguousarray(q), body, threads=threads)
        return xb + _rotate(qb, lpos), _qmul(qb, lquat)

    p0, q0 = frames(s)
    tpos, tquat = as_targets(targets)
    line = _Line(np.concatenate([p0, tpos]), np.concatenate([q0, tquat if tquat is not None else
                                                             np.repeat(q0, len(tpos), axis=0)]), step)

    # Waypoints (leg, u) along the line, and their arc length from the start.
    legs = np.concatenate([np.full(c, i) for i, c in enumerate(line.cuts)])
    us = np.concatenate([np.arange(1, c + 1) / c for c in line.cuts])
    before = np.concatenate([[0.0], np.cumsum(line.length)])

    def arc(leg: int, u: float) -> float:
        return float(before[leg] + u * line.length[leg])

    def points(leg_u: list[tuple[int, float]]) -> np.ndarray:
        """(N, 4, 4) frame poses on the line at ``(leg, u)`` each."""
        lu = np.asarray(leg_u, dtype=np.float64).reshape(-1, 2)
        T = np.zeros((len(lu), 4, 4))
        T[:, 3, 3] = 1
        for leg in np.unique(lu[:, 0]).astype(int):
            on = lu[:, 0] == leg
            T[on, :3, 3], T[on, :3, :3] = line.at(leg, lu[on, 1])
        return T

    def solve(leg_u: list[tuple[int, float]], q_from: np.ndarray):
        T = points(leg_u)
        return ik(robot, T, frame=frame, tool=tool, start=np.repeat(q_from[None], len(T), axis=0), seeds=1,
                  position_tolerance=position_tolerance / 100, rotation_tolerance=rotation_tolerance / 100,
                  locked=locked, threads=threads)

    arms = _lever_arms(robot, body, lpos)
    tols = (position_tolerance, rotation_tolerance)

    def strays(q: np.ndarray, seg_legs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on the frame's deviations from the line (metres, radians) anywhere on each
        segment of the joint path ``q`` (n + 1, K), each measured from its leg ``seg_legs[i]``
        (module docs: a few samples and the joints' motion), or, where the frame's chain has a
        slide or coupled joint, the largest found every 0.1 mm and 0.2 mrad."""
        d = np.diff(q, axis=0)
        wraps = robot.continuous
        d[:, wraps] = (d[:, wraps] + np.pi) % (2 * np.pi) - np.pi
        if arms is not None:
            return _bounded(line, frames, q, d, seg_legs, arms, tols)
        pw = frames(q)[0]
        n = np.clip(np.maximum(np.ceil(np.linalg.norm(np.diff(pw, axis=0), axis=1) / CHECK_SPACING),
                               np.ceil(np.abs(d).max(axis=1) / JOINT_SPACING)).astype(int) + 1, 2, 4000)
        seg = np.repeat(np.arange(len(d)), n)
        w = np.concatenate([np.linspace(0.0, 1.0, k) for k in n])[:, None]
        dist, ang = line.deviations(seg_legs[seg], *frames(robot.project(q[seg] + w * d[seg])))
        out_d, out_a = _largest(len(d), seg, dist, ang)
        return out_d, out_a

    def stray(qa: np.ndarray, qb: np.ndarray, leg: int) -> tuple[float, float]:
        """``strays`` of the one joint segment qa → qb, from leg ``leg``."""
        dist, ang = strays(np.stack([qa, qb]), np.array([leg]))
        return float(dist[0]), float(ang[0])

    path, reached_arc, reason = [s[0]], 0.0, ""
    worst = [0.0, 0.0]
    i = 0
    pending: list[tuple[int, float]] = list(zip(legs.tolist(), us.tolist()))
    inserted, budget = 0, 2 * len(pending) + 16     # waypoints added by halving, at most
    sol = solve(pending, s[0])
    # The common case at once: every waypoint solved from the start, every segment on the line.
    ok = np.cumprod(sol.certified).astype(bool)
    if ok.any():
        k = int(ok.sum())
        dists, angs = strays(np.concatenate([s, sol.poses[:k]]), legs[:k])
        good = np.cumprod((dists <= position_tolerance) & (angs <= rotation_tolerance)).astype(bool)
        i = int(good.sum())
        if i:
            path.extend(sol.poses[:i])
            worst = [float(dists[:i].max()), float(angs[:i].max())]
            reached_arc = arc(*pending[i - 1])
    while i < len(pending):
        leg, u = pending[i]
        if not sol.certified[i]:
            # (solved from the start: try again from the last pose on the line)
            again = solve(pending[i:], path[-1])
            if again.certified[0]:
                sol = _splice(sol, i, len(pending), again)
            else:
                where = arc(leg, u)
                reason = (f"no certified pose reaches the line at {where:.4g} {'rad' if line.turning_only else 'm'}: "
                          + ("it collides there" if again.outcome[0] == 2
                             else "out of reach from the last pose (a joint limit or a singularity)"))
                break
        qa, qb = path[-1], sol.poses[i]
        dist, ang = stray(qa, qb, leg)
        if dist > position_tolerance or ang > rotation_tolerance:
            # solved from the start, the pose may be on another branch: the rest from this pose
            again = solve(pending[i:], qa)
            if again.certified[0]:
                d2, a2 = stray(qa, again.poses[0], leg)
                if d2 <= position_tolerance and a2 <= rotation_tolerance:
                    sol = _splice(sol, i, len(pending), again)
                    dist, ang, qb = d2, a2, again.poses[0]
        halvings = 0
        prev_u = 0.0 if i == 0 or pending[i - 1][0] != leg else pending[i - 1][1]
        while (dist > position_tolerance or ang > rotation_tolerance) and halvings < _HALVINGS \
                and inserted < budget:
            # the joint segment leaves the line: a waypoint in the middle, solved from qa
            mid = (leg, 0.5 * (prev_u + u))
            m_sol = solve([mid], qa)
            if not m_sol.certified[0]:
                break
            pending.insert(i, mid)
            sol = _splice(sol, i, i, m_sol)
            inserted += 1
            leg, u = mid
            qb = sol.poses[i]
            dist, ang = stray(qa, qb, leg)
            halvings += 1
        if dist > position_tolerance or ang > rotation_tolerance:
            reason = (f"the frame leaves the line near {arc(leg, u):.4g} {'rad' if line.turning_only else 'm'} "
                      f"({dist * 1e3:.3g} mm, {ang * 1e3:.3g} mrad off it): a singularity or a joint limit")
            break
        worst = [max(worst[0], dist), max(worst[1], ang)]
        path.append(qb)
        reached_arc = arc(leg, u)
        i += 1

    q = np.asarray(path)
    if len(q) > 1:
        cert = certify_motions(robot, q[:-1], q[1:], threads=threads)
        bad = np.flatnonzero(~cert.certified)
        if len(bad):
            k = int(bad[0])
            what = "blocked" if cert.blocked[k] else "not proven free"
            q = q[:k + 1]
            # (the arc at waypoint k: recomputed from the frame, the nearest point of the line)
            reached_arc = _arc_of(line, frames(q[-1:])[0][0], before)
            reason = f"the joint motion after {reached_arc:.4g} {'rad' if line.turning_only else 'm'} is {what}"
    fraction = 1.0 if line.total == 0 else min(1.0, reached_arc / line.total)
    done = not reason
    return CartesianPath(path=q, fraction=1.0 if done else fraction, reached=done, reason=reason,
                         position_deviation=worst[0], rotation_deviation=worst[1],
                         seconds=time.perf_counter() - t0)


def _arc_of(line: _Line, p: np.ndarray, before: np.ndarray) -> float:
    best = (np.inf, 0.0)
    for leg in range(len(line.pos) - 1):
        a, b = line.pos[leg], line.pos[leg + 1]
        d = b - a
        u = float(np.clip((p - a) @ d / (d @ d), 0, 1)) if d @ d > 0 else 0.0
        dist = float(np.linalg.norm(a + u * d - p))
        if dist < best[0]:
            best = (dist, float(before[leg] + u * line.length[leg]))
    return best[1]


_PER_TARGET = ("poses", "reached", "certified", "position_error", "rotation_error", "iterations", "seeds", "outcome")


def _splice(sol: IKResult, start: int, stop: int, new: IKResult) -> IKResult:
    """``sol`` with its answers ``start:stop`` replaced by all of ``new``'s."""
    spliced: dict[str, Any] = {f: np.concatenate([getattr(sol, f)[:start], getattr(new, f), getattr(sol, f)[stop:]])
                               for f in _PER_TARGET}
    return replace(sol, notes={}, **spliced)
