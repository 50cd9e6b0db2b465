"""What "certified" means, once, for every pose and path profrobot returns as safe.

**Definition.** A pose is *certified free* when the exact labeller (``rust/collision/collide.rs``: MuJoCo's
collision rules, exact shapes) finds no candidate geom pair in contact **and** every candidate
pair more than :data:`CLEARANCE` metres apart. A path is certified free when every waypoint is
and every segment is *proven* so: at every pose of the segment's SO(2) interpolation, not only
at samples, every candidate pair keeps more than ``max(margin, CLEARANCE)`` (the continuous
certificate, :func:`certify_motions`; ``check_path(..., method="sampled")`` keeps the older
check of a dense re-interpolation). Nothing else in profrobot says "certified": not the learned
field (never on its word alone), not the plain labels.

**The continuous certificate** (``rust/planning/motion.rs``, conservative advancement). For each pair, an
upper bound on how fast its distance can shrink along the segment comes from the kinematic
chain (every joint below the pair's common ancestor times its lever: the largest distance from
its axis's anchor to the geom, over all configurations); a pose whose pair is ``d`` apart proves
the pair clear on the stretch of the segment it cannot close in. Poses are placed by halving
until every pair's stretches cover the segment; distances are lower bounds (bounding spheres, a
separating axis from exact support points, GJK's axis), less 1e-9 relative and absolute for
rounding. What is proven: every pose of the segment is certified free, exactly, up to that
rounding. A segment that passes within ~1e-7 rad of the clearance (the halving stops at 1e-7
rad of joint motion) or that needs more than 65 536 poses is *unproven* and never called free.

Why a clearance and not 0: touching is not free. MuJoCo reports a contact at zero distance (two
links that just meet, a joint clamped at the limit where fingers close), so a pose at distance
0 is a contact to MuJoCo and to a real robot; 1 µm keeps such poses out of what we call safe.
The plain labels (:func:`profrobot.label_poses`, :func:`profrobot.collides`) stay MuJoCo's own
verdict (contact at distance ≤ margin); certification is that verdict plus the clearance.

How it is computed, cheaply and exactly: the Rust fast path (``RobotModel.certified``,
``rust/collision/fastpath.rs``) decides each candidate pair "not in contact and more than CLEARANCE
apart", likeliest pairs first, and stops at the first pair that is not; box and sphere tests
inflated by the clearance clear most pairs without a distance, and the rest get the exact signed
distance the labels report. The verdict is that of labelling every pose with distances
(``~collides & (min_distance > CLEARANCE)``, tested), at about the cost of
:func:`profrobot.collides`. This module is torch-free (the base layer).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, overload

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from .labels import as_poses, check_threads, interpolate, label_poses, so2_steps
from ..robot.gate import Layout, with_layout, with_margin
from ..robot.margin import CLEARANCE as _MARGIN_CLEARANCE
from ..robot.robot import Robot

__all__ = ["CLEARANCE", "certify_poses", "certify_motions", "MotionCertificate", "first_contact", "FirstContact",
           "check_path", "path_free_at",
           "PathCheck", "certified_summary", "failures_of"]

#: metres: the least distance every candidate pair keeps in a certified pose (module docs; the
#: value lives in :mod:`profrobot.robot.margin`, beside the margins it is the floor of: a margin at most
#: this is no margin, and a layout within it of the robot's base is refused, ``Robot.at``)
CLEARANCE = _MARGIN_CLEARANCE
"""Metres: the least distance every candidate pair keeps in a certified pose (1e-6 m); a ``margin`` at most this is no margin."""


def certify_poses(robot: Robot, poses: npt.ArrayLike, *, layout: Layout | None = None, margin: float = CLEARANCE,
                  threads: int | None = None) -> np.ndarray:
    """(B,) bool: True where pose ``poses[i]`` ((B, K) or (K,), radians / metres; a family's θ
    with ``layout=δ``) is certified free (module docs: no contact, every candidate pair more than
    :data:`CLEARANCE` apart). A pose the robot cannot take (a limited joint outside its limits,
    a joint equality not met, to 1e-9: :meth:`Robot.feasible`) is never certified.

    ``margin``: metres every robot–obstacle pair must keep (:mod:`profrobot.robot.margin`: pass an
    estimated layout's :attr:`~profrobot.perception.layouts.LayoutEstimate.margin`, and a pose certified
    at the estimate is free at the true layout while the estimate's error stays below it)."""
    robot = with_margin(robot, margin)
    q = as_poses(robot, with_layout(robot, poses, layout))
    if len(q) == 0:
        return np.zeros(0, dtype=bool)
    return robot.core.certified(np.ascontiguousarray(q), CLEARANCE, threads=check_threads(threads))


@dataclass
class MotionCertificate:
    """The continuous certificate of B straight motions (module docs).

    Attributes:
        certified: (B,) bool, every pose of motion i is proven certified free.
        blocked: (B,) bool, a pose of motion i has a pair not shown above ``max(margin,
            CLEARANCE)`` (in contact, within the clearance, or a pair GJK gave no separating
            axis for): not free, or not provably so at that pose.
        unproven: (B,) bool, neither within the certificate's limits (module docs).
        blocked_at: (B,) float, the motion parameter t in [0, 1] of that pose (NaN otherwise).
        states: (B,) int, poses placed.
    """

    certified: np.ndarray
    blocked: np.ndarray
    unproven: np.ndarray
    blocked_at: np.ndarray
    states: np.ndarray


def certify_motions(robot: Robot, starts: npt.ArrayLike, goals: npt.ArrayLike, *, via: npt.ArrayLike | None = None,
                    layout: Layout | None = None, margin: float = CLEARANCE,
                    threads: int | None = None) -> MotionCertificate:
    """The continuous certificate (module docs) of each straight motion ``starts[i] → goals[i]``
    ((B, K) or (K,) each, radians / metres; a family's θ with ``layout=δ``): continuous hinges
    along the short arc, the motion :func:`profrobot.interpolate` replays; other joints
    straight; the dependent joints of joint equalities following their independent ones (for a
    nonlinear coupling that is a curve, and the curve is what is proven). Same answer for any
    thread count. A motion the robot cannot make (an end off its couplings, a limited joint
    outside its limits anywhere along it) is unproven, never certified. ``margin``: as for
    :func:`certify_poses`, at every pose of every motion.

    ``via`` ((B, K), the shape of ``starts``): each motion is instead the quadratic Bézier
    ``q(t) = s + 2t·(v − s) + t²·(g − 2v + s)`` from ``starts[i]`` bent towards ``via[i]`` to
    ``goals[i]`` (short arcs on continuous hinges): the parabolic blend a timed path takes at
    the corner ``via[i]`` (:func:`profrobot.time_path`). The same proof holds (each joint's speed
    is at most ``2·max(|v − s|, |g − v|)`` and it stays between its three control values), so a
    blend is proven as a straight motion is, never assumed from its chords."""
    robot = with_margin(robot, margin)
    a = as_poses(robot, with_layout(robot, starts, layout, "starts"), name="starts")
    b = as_poses(robot, with_layout(robot, goals, layout, "goals"), name="goals")
    if a.shape != b.shape:
        raise InputError(f"starts and goals must have the same shape; got {a.shape} and {b.shape}")
    v = None
    if via is not None:
        v = as_poses(robot, with_layout(robot, via, layout, "via"), name="via")
        if v.shape != a.shape:
            raise InputError(f"via must have the shape of starts; got {v.shape} and {a.shape}")
        v = np.ascontiguousarray(v)
    out = robot.core.certify_motions(np.ascontiguousarray(a), np.ascontiguousarray(b), CLEARANCE, via=v,
                                     threads=check_threads(threads))
    verdict = out["verdict"]
    return MotionCertificate(certified=verdict == 0, blocked=verdict == 1, unproven=verdict == 2,
                             blocked_at=out["blocked_at"], states=out["states"])


@dataclass
class FirstContact:
    """Where a straight motion first stops being free (:func:`first_contact`).

    Attributes:
        certified: the whole motion is proven free (then there is no contact: ``t`` is NaN).
        t: the motion parameter in [0, 1] of the first pose not certified free (in contact, or
            within ``max(margin, CLEARANCE)`` of it; or where no proof reaches further, within
            the certificate's resolution of that), to ``tolerance``; NaN when ``certified``.
        free_until: every pose of the motion up to this parameter is proven free (``t`` −
            ``free_until`` ≤ ``tolerance``; 1.0 when ``certified``).
        pose: (K,) the pose at ``t`` (None when ``certified``); ``before``: (K,) the pose at
            ``free_until``, proven free.
        pairs: the geom pairs in contact at ``pose`` (none when it is only within the clearance).
        certificates: straight motions certified on the way (the search's cost).
    """

    certified: bool
    t: float
    free_until: float
    pose: np.ndarray | None
    before: np.ndarray
    pairs: list[tuple[str, str]]
    certificates: int


def first_contact(robot: Robot, start: npt.ArrayLike, goal: npt.ArrayLike, *, layout: Layout | None = None,
                  margin: float = CLEARANCE, tolerance: float = 1e-6, threads: int | None = None) -> FirstContact:
    """The first pose of the straight motion ``start → goal`` ((K,) each; the motion
    :func:`certify_motions` proves and :func:`profrobot.interpolate` replays) that is not certified
    free: where a closing gripper first touches the part, where an approach first meets the table.

    ``MotionCertificate.blocked_at`` is *a* pose where the proof failed, not the first one. Here
    the continuous certificate bisects: the motion is proven free on ``[0, free_until]`` and the
    pose at ``t`` is not certified free (a pair in contact or within ``max(margin, CLEARANCE)``),
    with ``t − free_until ≤ tolerance``. Every step keeps both facts, so the answer is exact to
    ``tolerance``, not sampled. A start that is not free itself gives ``t = 0``."""
    robot = with_margin(robot, margin)
    a = as_poses(robot, with_layout(robot, start, layout, "start"), name="start", check_limits=True)
    b = as_poses(robot, with_layout(robot, goal, layout, "goal"), name="goal", check_limits=True)
    if len(a) != 1 or len(b) != 1:
        raise InputError(f"start and goal must each be one pose (K,); got {np.shape(start)} and {np.shape(goal)}")
    if not (isinstance(tolerance, (int, float)) and not isinstance(tolerance, bool) and 0 < tolerance < 1):
        raise InputError(f"tolerance must be a number in (0, 1) (of the motion parameter); got {tolerance!r}")
    a, b = a[0], b[0]
    step = so2_steps(robot, np.stack([a, b]))[0]

    def at(t: float) -> np.ndarray:
        """The motion's pose at ``t``: the independent joints straight (continuous ones on the
        short arc), the dependent ones on their couplings."""
        return robot.project(a + t * step)

    threads = check_threads(threads)
    count = [0]

    def proven(t0: float, t1: float) -> MotionCertificate:
        count[0] += 1
        return certify_motions(robot, at(t0), at(t1), threads=threads)

    def clear(t: float) -> bool:
        return bool(certify_poses(robot, at(t)[None], threads=threads)[0])

    whole = proven(0.0, 1.0)
    if whole.certified[0]:
        return FirstContact(True, float("nan"), 1.0, None, b, [], count[0])
    # invariant: [0, lo] proven free; the pose at hi not certified free (or, where the proof
    # cannot go on, within the certificate's resolution of that)
    lo, hi = 0.0, 1.0
    if not clear(0.0):
        hi = 0.0
    elif whole.blocked[0] and not clear(float(whole.blocked_at[0])):
        hi = float(whole.blocked_at[0])
    while hi - lo > tolerance:
        mid = 0.5 * (lo + hi)
        if not clear(mid):
            hi = mid
            continue
        reach = mid   # the pose at mid is free: prove [lo, reach], halving the reach until it is
        while True:
            c = proven(lo, reach)
            if c.certified[0]:
                lo = reach
                break
            tb = lo + float(c.blocked_at[0]) * (reach - lo) if c.blocked[0] else float("nan")
            if c.blocked[0] and not clear(tb):
                hi = tb
                break
            reach = 0.5 * (lo + reach)
            if reach - lo <= 0.25 * tolerance:   # no proof goes further: the certificate's resolution
                hi = reach
                break
    q = at(hi)
    lab = label_poses(robot, q[None], pairs=True, check_limits=False)
    names = [] if lab.colliding_pairs is None else [robot.pair_names(int(k)) for k in lab.colliding_pairs[:, 1]]
    return FirstContact(False, hi, lo, q, at(lo), names, count[0])


@dataclass
class PathCheck:
    """The exact labeller's verdict on a path of S waypoints.

    Attributes:
        certified: the whole path is certified free: every waypoint, and every segment (proven
            continuously, or every dense sample with ``method="sampled"``).
        waypoint_uncertified: (S,) bool, waypoint i is not certified free.
        segment_uncertified: (S−1,) bool, segment i (waypoints i and i+1, its end points included)
            is not certified free somewhere (or, continuously, not proven free).
        dense: the poses checked one by one, radians / metres: ((S−1)·density + 1, K) sampled;
            the S waypoints with the continuous certificate (which proves the segments between).
        dense_uncertified: (D,) bool.
        method: ``"continuous"`` or ``"sampled"``.
    """

    certified: bool
    waypoint_uncertified: np.ndarray
    segment_uncertified: np.ndarray
    dense: np.ndarray
    dense_uncertified: np.ndarray
    method: str = "sampled"

    @property
    def uncertified_segments(self) -> np.ndarray:
        """Indices i of segments [i, i+1] that are not certified free somewhere."""
        return np.flatnonzero(self.segment_uncertified)


def check_path(robot: Robot, path: npt.ArrayLike, density: int = 10, *, layout: Layout | None = None,
               margin: float = CLEARANCE, method: Literal["continuous", "sampled"] = "continuous") -> PathCheck:
    """Certifies ``path`` (S, K) waypoints (a family's θ with ``layout=δ``) and the SO(2) segments
    between them: continuously (every pose of every segment proven, module docs), or with
    ``method="sampled"`` at the ``density − 1`` interpolated poses between each consecutive pair
    (``density`` times finer than the waypoints; the continuous certificate needs no density
    and ignores it). A waypoint the robot cannot take (:meth:`Robot.feasible`) is not certified,
    nor are its segments. ``margin``: as for :func:`certify_poses`."""
    robot = with_margin(robot, margin)
    path = as_poses(robot, with_layout(robot, path, layout, "path"), name="path")
    if path.ndim != 2 or len(path) < 2:
        raise InputError(f"path must have shape (S >= 2, K); got {path.shape}")
    if isinstance(density, bool) or not isinstance(density, (int, np.integer)) or density < 1:
        raise InputError(f"density must be a positive integer; got {density!r}")
    if method not in ("continuous", "sampled"):
        raise InputError(f"method must be 'continuous' or 'sampled'; got {method!r}")
    if method == "continuous":
        path = as_poses(robot, path, name="path")
        hit = ~certify_poses(robot, path)
        seg_hit = ~certify_motions(robot, path[:-1], path[1:]).certified | hit[:-1] | hit[1:]
        # (every waypoint ends a segment, so a failing waypoint fails a segment too)
        return PathCheck(certified=not seg_hit.any(), waypoint_uncertified=hit,
                         segment_uncertified=seg_hit, dense=path, dense_uncertified=hit, method="continuous")
    S, K = path.shape
    ok = robot.feasible(path)
    if not ok.all():  # off its couplings or outside its limits: nothing to sample, nothing certified
        bad = ~ok
        return PathCheck(certified=False, waypoint_uncertified=bad, segment_uncertified=bad[:-1] | bad[1:], dense=path,
                         dense_uncertified=bad, method="sampled")
    # (S−1, density+1, K): each segment with both its end points, so every segment is whole
    seg = interpolate(robot, path[:-1], path[1:], int(density) + 1)
    dense = np.concatenate([seg[:, :-1].reshape(-1, K), path[-1:]], axis=0)
    hit = ~certify_poses(robot, dense)
    seg_hit = np.zeros(S - 1, dtype=bool)
    idx = np.arange(len(dense))
    # dense sample j lies in segment j // density; a shared end point belongs to both neighbours
    seg_hit[np.minimum(idx[hit] // density, S - 2)] = True
    ends = idx[hit][(idx[hit] % density == 0) & (idx[hit] > 0)] // density - 1
    seg_hit[ends[ends >= 0]] = True
    return PathCheck(certified=not hit.any(), waypoint_uncertified=hit[::density], segment_uncertified=seg_hit,
                     dense=dense, dense_uncertified=hit, method="sampled")


def path_free_at(robot: Robot, path: npt.ArrayLike, resolution: float, *, margin: float = CLEARANCE) -> bool:
    """Whether ``path`` (S, K) is certified free when re-interpolated (SO(2)) so that no joint
    moves more than ``resolution`` (rad / m) between two checked poses: the planner's own
    guarantee (:func:`profrobot.plan_path`), independent of how far apart the waypoints are.
    ``margin``: as for :func:`certify_poses`."""
    robot = with_margin(robot, margin)
    path = as_poses(robot, path, name="path")
    if not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive number; got {resolution!r}")
    if not robot.feasible(path).all():
        return False
    d = so2_steps(robot, path)
    counts = np.maximum(np.ceil(np.abs(d).max(axis=1) / resolution).astype(int), 1)
    poses = np.concatenate([interpolate(robot, a, b, int(n) + 1)[1:] for a, b, n in zip(path[:-1], path[1:], counts)])
    return bool(certify_poses(robot, np.concatenate([path[:1], poses])).all())


def certified_summary(certified: npt.ArrayLike | None) -> str:
    """"87.5% certified free (1 failure)" for a (B,) bool verdict, "not checked" for None."""
    if certified is None:
        return "not checked (no scene to certify against: pass robot= or a field)"
    c = np.asarray(certified, dtype=bool)
    n = int((~c).sum())
    return f"{c.mean():.1%} certified free ({n} failure{'s' * (n != 1)})"


@overload
def failures_of(certified: None) -> None: ...
@overload
def failures_of(certified: np.ndarray) -> np.ndarray: ...
@overload
def failures_of(certified: np.ndarray | None) -> np.ndarray | None: ...
def failures_of(certified: npt.ArrayLike | None) -> np.ndarray | None:
    """Indices where a (B,) verdict is not certified free; None when nothing was checked."""
    return None if certified is None else np.flatnonzero(~np.asarray(certified, dtype=bool))
