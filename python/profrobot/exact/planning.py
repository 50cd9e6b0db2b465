"""Global paths over the exact labeller: RRT-Connect in joint space, shortcut, in Rust.

:func:`plan_path` answers "a free path between these two free poses, or a clear *none found*":
it tries the straight SO(2) path, then grows two trees (RRT-Connect), then shortcuts the path
(a pair of waypoints found blocked is not tried again until the path changes).

Every returned edge is **certified continuously** (``check="continuous"``, the default;
:mod:`profrobot.exact.certification`): every pose of the edge, not only samples, is proven to keep
every candidate pair more than ``max(margin, CLEARANCE)`` apart, by conservative advancement on
the exact labeller's shapes. The search explores with edges sampled at 0.05 rad and proves only
the path it returns, repairing a segment that fails with a search whose every edge is proven
(``rust/planning/plan.rs``). With ``check="sampled"`` edges are checked densely instead (no joint
moves more than ``resolution`` between two labelled poses) and the answer is verified ``verify``
(10) times finer, re-planning any segment that fails: a thin part can still pass a thin obstacle
between two samples. Either way every segment of the result is an SO(2) interpolation, so
:func:`profrobot.interpolate` between consecutive waypoints replays exactly the motion that was
checked. Same seed, same path, whatever the thread count.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Sequence
from typing import Literal

import numpy as np
import numpy.typing as npt

from .labels import as_poses, check_threads, label_poses, so2_steps
from ..robot.robot import Robot
from .certification import CLEARANCE, path_free_at
from ..robot import gate
from ..robot.gate import Layout
from ..errors import InputError

PlanStatus = Literal["direct", "connected", "time_out", "iteration_limit"]


@dataclass
class PathResult:
    """A planning result.

    Attributes:
        path: (M, K) waypoints, start first and goal last (radians / metres; continuous hinges
            in [-pi, pi)); (0, K) when none was found.
        found: whether ``path`` joins start and goal (the planner's own verdict: every returned
            edge certified continuously, or labelled at ``resolution`` with ``check="sampled"``).
        certified: the path is certified free (:mod:`profrobot.exact.certification`): continuously,
            each returned segment proven by the planner with the certificate :func:`check_path`
            runs, or, with ``check="sampled"``, every pose re-interpolated at ``resolution`` checked
            again after planning; False when nothing was found.
        status: ``"direct"`` (the straight path is free), ``"connected"`` (the trees met),
            ``"time_out"`` or ``"iteration_limit"`` (none found within the budget).
        checks: poses placed by the continuous certificate and its refutation pre-check, or
            labelled (``check="sampled"``).
        seconds: the planner's wall time (search, shortcutting and, sampled, verification);
            the certificate checked again after it is not included.
        iterations: tree extensions made.
        tree_sizes: nodes in the start and goal trees.
        raw_waypoints: waypoints before shortcutting.
        reason: one line saying why nothing was found ('' when found).
        shortcut_seconds: of ``seconds``, the time spent shortcutting the path the search found.
    """

    path: np.ndarray
    found: bool
    status: PlanStatus
    checks: int
    seconds: float
    iterations: int
    tree_sizes: tuple[int, int]
    raw_waypoints: int
    reason: str = ""
    certified: bool = False
    shortcut_seconds: float = 0.0

    def summary(self) -> str:
        if not self.found:
            return f"no path: {self.reason}"
        return (f"{self.status}: {len(self.path)} waypoints (from {self.raw_waypoints}), "
                f"{'certified free' if self.certified else 'NOT certified (a contact within the clearance)'}, "
                f"{self.checks} checks, {self.seconds * 1e3:.1f} ms")


def so2_length(robot: Robot, path: np.ndarray) -> float:
    """L2 length of a waypoint path (M, K), continuous hinges along the short arc."""
    return float(np.linalg.norm(so2_steps(robot, path), axis=1).sum())


def _colliding_end(robot: Robot, ends: np.ndarray, threads: int | None) -> InputError | None:
    """The :class:`InputError` naming a pair in contact where the start or the goal (``ends``,
    (2, K)) collides; None where neither does."""
    lab = label_poses(robot, ends, pairs=True, threads=threads)
    for i, name in enumerate(("start", "goal")):
        if lab.collides[i]:
            assert lab.colliding_pairs is not None   # asked for: pairs=True
            k = lab.colliding_pairs[lab.colliding_pairs[:, 0] == i][0, 1]
            within = f" or is within margin={robot.margin:g} m of" if robot.margin > 0 else ""
            return InputError(f"{name} collides{within} ({' / '.join(robot.pair_names(int(k)))}); plan between free poses")
    return None


def plan_path(robot: Robot, start: npt.ArrayLike, goal: npt.ArrayLike, *, layout: Layout | None = None,
              margin: float = CLEARANCE, resolution: float = 0.01, max_time: float = 10.0, seed: int = 0,
              range: float = 0.0, iterations: int = 200_000, shortcut_rounds: int = 200, verify: int = 10,
              check: Literal["continuous", "sampled"] = "continuous", locked: Sequence[str] = (),
              threads: int | None = None) -> PathResult:
    """A collision-free path from ``start`` to ``goal`` (each (K,), free and within limits).

    Args:
        resolution: with ``check="sampled"``, the largest joint move between two labelled poses
            along any edge (rad / m); the continuous certificate needs none.
        max_time: wall-clock budget in seconds (> 0); the call returns by then (give or take
            one edge check) with ``found=False`` if no path was found.
        seed: the sampler's seed; the same seed gives the same path for any thread count.
        range: longest tree extension (L2 in joint space; a blocked one retries a quarter of
            it); 0 picks 0.1 × the joint-space diagonal (half OMPL's default: MotionBenchMaker's
            p95 halved, the bundled scenes' medians level or lower).
        iterations: a deterministic budget of tree extensions.
        shortcut_rounds: shortcut attempts on the found path.
        verify: with ``check="sampled"``, the answer is re-checked ``verify`` times finer than
            ``resolution`` (a thin feature or a grazing contact can slip between two samples of
            the search); a segment that fails is re-planned at the fine resolution. 1 turns this
            off.
        check: ``"continuous"`` (every returned edge proven free at every pose, module docs) or
            ``"sampled"`` (every edge labelled at ``resolution``).
        margin: metres the path keeps from every obstacle (:mod:`profrobot.robot.margin`; an estimated
            layout's :attr:`~profrobot.perception.layouts.LayoutEstimate.margin`): the start and goal must
            keep it too.
        layout: a family's layout δ: the path is planned over its θ with the obstacles pinned
            there (``robot.at(layout)``; :mod:`profrobot.robot.gate`).
        locked: names of joints no waypoint moves (a gripper's jaw while the arm moves): start
            and goal must agree on them.

    Raises ValueError naming the problem for a colliding or out-of-limits start or goal (and,
    with the continuous certificate, a start or goal within ``CLEARANCE`` of contact, which no
    proven motion can leave), mismatched lengths, NaN, a non-positive ``max_time`` or
    ``resolution``, an unknown ``check``.
    """
    robot = gate.robot_at(robot, layout=layout, margin=margin)
    s = as_poses(robot, start, name="start", check_limits=True)
    g = as_poses(robot, goal, name="goal", check_limits=True)
    if s.shape != (1, robot.njoint) or g.shape != (1, robot.njoint):
        raise InputError(f"start and goal must each be one pose of {robot.njoint} joints; got shapes "
                         f"{np.shape(start)} and {np.shape(goal)}")
    resolution, max_time = gate.positive("resolution", resolution), gate.positive("max_time", max_time)
    seed = gate.seed(seed)
    held = gate.joint_mask(robot, locked, "locked")
    if held is not None:
        moved = [n for j, n in enumerate(robot.joint_names) if held[j] and s[0, j] != g[0, j]]
        if moved:
            raise InputError(f"locked joints must keep one value: start and goal differ in {', '.join(moved)}")
    verify = gate.count("verify", verify, why="1: no verification")
    if check not in ("continuous", "sampled"):
        raise InputError(f"check must be 'continuous' or 'sampled'; got {check!r}")
    try:
        out = robot.core.plan_path(s[0], g[0], resolution=float(resolution), max_time=float(max_time), seed=int(seed),
                                   range=float(range), max_iterations=int(iterations),
                                   shortcut_rounds=int(shortcut_rounds), verify=int(verify),
                                   continuous=check == "continuous", clearance=CLEARANCE, held=held,
                                   threads=check_threads(threads))
    except InputError:
        # (the core refuses a colliding start or goal without naming the pair: the ends are
        # labelled only then, not before every call; a colliding end is named before the core's
        # other refusals, as when they were labelled first)
        named = _colliding_end(robot, np.concatenate([s, g]), check_threads(threads))
        if named is None:
            raise
        raise named from None
    status = out["status"]
    found = status in ("direct", "connected")
    reason = "" if found else {
        "time_out": f"no path within max_time={max_time} s ({out['iterations']} extensions, trees of "
                    f"{out['tree_sizes'][0]} and {out['tree_sizes'][1]} nodes); the goal may be enclosed",
        "iteration_limit": f"no path within iterations={iterations}; the goal may be enclosed",
    }[status]
    path = np.asarray(out["path"]).reshape(-1, robot.njoint)
    return PathResult(path=path, found=found, status=status,
                      checks=int(out["checks"]), seconds=float(out["seconds"]), iterations=int(out["iterations"]),
                      tree_sizes=(int(out["tree_sizes"][0]), int(out["tree_sizes"][1])), raw_waypoints=int(out["raw_waypoints"]),
                      reason=reason, shortcut_seconds=float(out["shortcut_seconds"]),
                      # continuous: every returned segment was proven by the planner with the
                      # certificate check_path runs (certify_motion, CLEARANCE), its ends too
                      certified=found and (check == "continuous" or path_free_at(robot, path, float(resolution))))


def resample_path(robot: Robot, path, steps: int) -> np.ndarray:
    """(steps, K) poses along a waypoint path, evenly by SO(2) arc length, keeping every waypoint.

    Every original waypoint is kept (a chord that cut a corner would leave the checked path), and
    the remaining ``steps - M`` poses are spread over the segments in proportion to their length.
    """
    from .labels import interpolate

    p = as_poses(robot, path, name="path")
    m = len(p)
    steps = gate.count("steps", steps, max(m, 2), why=f"the path's {m} waypoints, and at least 2")
    if m == 1:
        return np.repeat(p, steps, axis=0)
    seg = np.linalg.norm(so2_steps(robot, p), axis=1)
    extra = steps - m
    # Largest-remainder split of the extra poses over the segments, by length.
    share = seg / seg.sum() * extra if seg.sum() > 0 else np.full(m - 1, extra / (m - 1))
    inner = np.floor(share).astype(int)
    for i in np.argsort(-(share - inner), kind="stable")[: extra - inner.sum()]:
        inner[i] += 1
    out = [p[:1]]
    for i in range(m - 1):
        out.append(interpolate(robot, p[i], p[i + 1], int(inner[i]) + 2)[1:])
    return np.concatenate(out)
