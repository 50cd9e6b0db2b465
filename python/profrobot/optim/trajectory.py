"""Collision-aware trajectories (paper supplement, "Collision-free Trajectory"): SO(2)
interpolation between two free poses, then either

- ``"penalty"``: Adam on the interior waypoints of γ1·mean L_SDF + γ2·TV with the end points
  fixed, TV = mean ‖θ_{i+1} − θ_i‖ over the whole path; or
- ``"tangent"``: Algorithm 1, a walk from start to goal along the L1 goal gradient, projected
  onto the tangent plane of ∇g where it would climb into the obstacle margin; the walk is then
  resampled to ``steps`` waypoints by arc length.

Straight interpolations that collide deeply (joints over ±2π, obstacles across the straight
line) trap both local methods. ``init="auto"`` (default) therefore starts such problems from a
global path found by the exact labeller (:func:`profrobot.plan_path`, RRT-Connect + shortcut),
resampled to ``steps`` waypoints, then *smooths* it with the field (γ1·mean L_SDF + γ2·TV,
keeping the shortest iterate that the exact labeller certifies); if smoothing never yields a
certified path, the certified planner path itself is returned, never a colliding one.
``sdf=None`` runs the exact planner alone.

Every result is verified by the exact labeller at the waypoints and on a dense re-interpolation
between them (:func:`~profrobot.exact.certification.check_path`).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np
import numpy.typing as npt
import torch

from ..exact.certification import CLEARANCE, PathCheck, check_path
from ..errors import InputError, InputTypeError
from ..field.identity import Field, field_robot
from ..field.layout import field_at_layout
from ..kinematics.limits import Limits
from ..exact.labels import interpolate
from ..robot.robot import Robot
from ..robot.gate import Layout, finite, positive, poses_within_limits, with_margin
from .paths import PenaltyOptions, TangentOptions, penalty_descent, smooth_certified, tangent_walk, unwrap_path

__all__ = ["plan_trajectory", "plan_trajectories", "TrajectoryResult", "trajectory_result", "PenaltyOptions", "TangentOptions"]

Method = Literal["penalty", "tangent"]
Init = Literal["auto", "straight", "planner"]
METHODS: tuple[str, ...] = get_args(Method)
INITS: tuple[str, ...] = get_args(Init)


@dataclass
class TrajectoryResult:
    """A path and the exact labeller's verdict on it.

    Attributes:
        path: (S, K) float64 waypoints, radians / metres, ``path[0]`` = start, ``path[-1]`` = goal.
        certified: the whole path is certified free (:func:`profrobot.exact.certification.check_path`,
            continuous: every waypoint certified and every segment proven free at every pose, the
            dependent joints of joint equalities following their independent ones).
        waypoint_uncertified: (S,) bool; segment_uncertified: (S−1,) bool (segment i: waypoints i, i+1).
        g: (S,) float32, the field along the path (NaN without a field).
        method: what produced the path ("penalty", "tangent", "planner", "planner+smooth",
            "images", "images+field", "images+planner", "video", "video+field").
        iterations: optimiser steps (penalty: Adam steps; tangent: walk steps).
        length: Σ‖θ_{i+1} − θ_i‖ (radians, continuous joints the short way); straight_length: the
            same for the straight SO(2) interpolation; relative_length = length / straight_length.
        seconds: wall time of the batched call that produced it, shared by its problems.
    """

    path: np.ndarray
    certified: bool
    waypoint_uncertified: np.ndarray
    segment_uncertified: np.ndarray
    g: np.ndarray
    method: str
    iterations: int
    length: float
    straight_length: float
    seconds: float
    check: PathCheck = field(repr=False)
    initial_certified: bool = False                     # the straight interpolation was certified
    init: str = "straight"
    planner: object = field(default=None, repr=False)   # the PathResult when init used the planner
    smoothed: bool = False
    length_before: float = float("nan")                 # the resampled planner path's length

    @property
    def relative_length(self) -> float:
        return self.length / self.straight_length if self.straight_length > 0 else 1.0

    @property
    def colliding_waypoints(self) -> np.ndarray:
        return np.flatnonzero(self.waypoint_uncertified)

    @property
    def uncertified_segments(self) -> np.ndarray:
        return np.flatnonzero(self.segment_uncertified)

    def summary(self) -> str:
        where = "" if self.certified else (f": {len(self.uncertified_segments)} colliding segment(s), "
                                           f"first at {self.uncertified_segments[:1].tolist()}")
        return (f"{self.method} path of {len(self.path)} waypoints, "
                f"{'certified free' if self.certified else 'NOT certified'}{where}; "
                f"length {self.relative_length:.2f}× the straight interpolation, {self.iterations} iterations")


def trajectory_result(robot: Robot, path: np.ndarray, check: PathCheck, *, g: np.ndarray, method: str,
                      iterations: int, seconds: float, straight_length: float | None = None,
                      **extra) -> TrajectoryResult:
    """A :class:`TrajectoryResult` for ``path`` (S, K) and its certificate ``check``; lengths
    along the short arc of continuous joints (``straight_length`` default: start to goal)."""
    lim = Limits.of(robot)
    if straight_length is None:
        straight_length = float(np.linalg.norm(lim.diff(path[-1], path[0])))
    return TrajectoryResult(path=path, certified=check.certified, waypoint_uncertified=check.waypoint_uncertified,
                            segment_uncertified=check.segment_uncertified, g=g, method=method, iterations=int(iterations),
                            length=float(np.linalg.norm(lim.diff(path[1:], path[:-1]), axis=1).sum()),
                            straight_length=float(straight_length), seconds=float(seconds), check=check, **extra)


def _planner_paths(robot: Robot, s: np.ndarray, g: np.ndarray, steps: int, options: dict) -> list:
    """A certified planner path per problem, resampled to ``steps`` waypoints (None when the
    planner found none, or needs more waypoints than ``steps``)."""
    from ..exact.planning import plan_path, resample_path

    out = []
    for b in range(len(s)):
        res = plan_path(robot, s[b], g[b], **{"seed": b, **options})
        path = resample_path(robot, res.path, steps) if res.found and len(res.path) <= steps else None
        out.append((res, path))
    return out


def plan_trajectories(sdf: Field | None, starts: npt.ArrayLike, goals: npt.ArrayLike, steps: int = 100,
                      method: Method = "penalty", *, robot: Robot | None = None, layout: Layout | None = None,
                      margin: float = CLEARANCE, init: Init = "auto", planner: dict | None = None,
                      penalty: PenaltyOptions | None = None, tangent: TangentOptions | None = None,
                      smooth_iterations: int = 300, l_thres: float = -0.1, density: int = 10) -> list[TrajectoryResult]:
    """B problems optimised together: ``starts`` and ``goals`` (B, K) → B :class:`TrajectoryResult`,
    in order; every option as :func:`plan_trajectory` (``frame_targets`` plans one problem only)."""
    if np.ndim(starts) != 2 or np.ndim(goals) != 2:
        raise InputError(f"plan_trajectories takes (B, K) starts and goals; got shapes {np.shape(starts)} and "
                         f"{np.shape(goals)} (plan_trajectory plans one problem)")
    return _plan(sdf, starts, goals, steps, method, robot=robot, init=init, planner=planner, penalty=penalty,
                 tangent=tangent, smooth_iterations=smooth_iterations, l_thres=l_thres, density=density,
                 layout=layout, margin=margin)


def plan_trajectory(sdf: Field | None, start: npt.ArrayLike, goal: npt.ArrayLike, steps: int = 100,
                    method: Method = "penalty", *, robot: Robot | None = None, layout: Layout | None = None,
                    margin: float = CLEARANCE, init: Init = "auto", planner: dict | None = None,
                    penalty: PenaltyOptions | None = None, tangent: TangentOptions | None = None,
                    smooth_iterations: int = 300, l_thres: float = -0.1, density: int = 10, frame: str | None = None,
                    frame_targets: dict | None = None) -> TrajectoryResult:
    """A collision-aware path from ``start`` to ``goal`` (K,) (radians / metres, within the joint
    limits), with ``steps`` waypoints including both ends: one :class:`TrajectoryResult`. B
    problems optimised together: :func:`plan_trajectories`.

    ``init``: ``"straight"`` optimises the straight SO(2) interpolation with ``method``;
    ``"planner"`` starts every problem from :func:`profrobot.plan_path` (``planner``: its
    options, e.g. ``dict(resolution=0.01, max_time=10.0)``), resampled to ``steps`` waypoints and
    smoothed with the field for ``smooth_iterations`` Adam steps (:func:`~profrobot.optim.paths.smooth_certified`:
    the shortest certified iterate kept; the certified planner path itself if none is shorter);
    ``"auto"`` (default) does ``"straight"`` where the straight path is certified at the dense
    check and ``"planner"`` where it is not. ``sdf=None`` (``robot`` required): exact planning and
    shortcutting only. ``scene``: for a field of a family of scenes
    (:mod:`profrobot.robot.family`), the layout δ to work at; answers are certified at exactly that layout.

    ``method="penalty"``: :func:`~profrobot.optim.paths.penalty_descent` with ``penalty``
    (a :class:`~profrobot.optim.PenaltyOptions`; default: ``PenaltyOptions(l_thres=l_thres,
    density=density)``), each problem stopping once its path is certified; ``method="tangent"``:
    Algorithm 1, :func:`~profrobot.optim.paths.tangent_walk` with ``tangent`` (a
    :class:`~profrobot.optim.TangentOptions`). ``l_thres``: the field threshold of the default
    options. ``density``: only for the older sampled certificate (``check_path(...,
    method="sampled")``, and the default ``PenaltyOptions``); the certificate of every result is
    continuous and needs none. ``robot``: the labeller's robot (default: the field's own).

    End-effector terms: ``frame_targets`` ``{waypoint index: (4, 4) world transform or (3,)
    position}`` of ``frame`` (a site, body or geom) at interior waypoints (one problem, not a
    batch). Each such waypoint is the certified IK pose (:func:`profrobot.ik`) nearest the
    straight path's waypoint there that puts the frame on its target (0.1 mm, 1 mrad); the path
    between consecutive fixed waypoints is planned as above, and the whole path certified.

    ``margin``: metres every certified path keeps from the obstacles (:mod:`profrobot.robot.margin`;
    an estimated layout's :attr:`~profrobot.perception.layouts.LayoutEstimate.margin`).
    """
    if np.ndim(start) != 1 or np.ndim(goal) != 1:
        raise InputError(f"plan_trajectory plans one problem: start and goal (K,); got shapes {np.shape(start)} and "
                         f"{np.shape(goal)} (plan_trajectories plans B problems together)")
    if frame_targets is not None or frame is not None:
        return _through_frame_targets(sdf, start, goal, steps, method, robot=robot, init=init, planner=planner,
                                      penalty=penalty, tangent=tangent, smooth_iterations=smooth_iterations,
                                      l_thres=l_thres, density=density, layout=layout, frame=frame,
                                      frame_targets=frame_targets, margin=margin, t0=time.perf_counter())
    return _plan(sdf, start, goal, steps, method, robot=robot, init=init, planner=planner, penalty=penalty,
                 tangent=tangent, smooth_iterations=smooth_iterations, l_thres=l_thres, density=density,
                 layout=layout, margin=margin)[0]


def _plan(sdf, start, goal, steps: int, method: Method, *, robot: Robot | None, init: Init, planner: dict | None,
          penalty: PenaltyOptions | None, tangent: TangentOptions | None, smooth_iterations: int, l_thres: float,
          density: int, layout, margin: float) -> list[TrajectoryResult]:
    """The problems of :func:`plan_trajectory` (one) and :func:`plan_trajectories` (B), together."""
    t0 = time.perf_counter()
    sdf, robot = field_at_layout(sdf, robot, layout)
    if sdf is None:
        if not isinstance(robot, Robot):
            raise InputError("plan_trajectory(sdf=None) plans with the exact labeller alone and needs robot=")
    else:
        robot = field_robot(sdf, robot)
    robot = with_margin(robot, margin)
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}; got {method!r}")
    if init not in INITS:
        raise InputError(f"init must be one of {INITS}; got {init!r}")
    if sdf is None and init == "straight":
        raise InputError("init='straight' optimises with the field; with sdf=None use init='auto' or 'planner'")
    if planner is not None and not isinstance(planner, dict):
        raise InputTypeError(f"planner must be a dict of plan_path options; got {type(planner).__name__}")
    l_thres = finite("l_thres", l_thres)
    density = positive("density", density, integer=True)
    penalty, tangent, smooth_iterations = _options(penalty, tangent, smooth_iterations, l_thres, density)
    s = poses_within_limits(robot, start, "start")
    g = poses_within_limits(robot, goal, "goal")
    if s.shape != g.shape:
        raise InputError(f"start and goal must have the same shape; got {s.shape} and {g.shape}")
    steps = positive("steps", steps, integer=True)
    if steps < 3:
        raise InputError(f"steps must be >= 3 (the end points are fixed); got {steps}")

    limits = Limits.of(robot, sdf.joint_limits if sdf is not None else None)
    straight = interpolate(robot, s, g, steps)          # (B, S, K): SO(2), from the Rust core
    initial_certified = np.array([check_path(robot, p, density).certified for p in straight], dtype=bool)
    use_planner = np.ones(len(s), dtype=bool) if init == "planner" else (
        ~initial_certified if init == "auto" else np.zeros(len(s), dtype=bool))
    paths = limits.numpy(straight.copy())
    n_iter = np.zeros(len(s), dtype=np.int64)
    straight_rows = np.flatnonzero(~use_planner)
    if len(straight_rows) and sdf is not None:         # without a field a free straight path stays as it is
        if method == "penalty":
            sub = unwrap_path(straight[straight_rows], limits.cont_np)
            it = penalty_descent(sdf, robot, sub, penalty)
        else:
            sub, it = tangent_walk(sdf, robot, s[straight_rows], g[straight_rows], steps, tangent)
        paths[straight_rows], n_iter[straight_rows] = limits.numpy(sub), it
    plans: dict[int, object] = {}
    before: dict[int, float] = {}
    smoothed = np.zeros(len(s), dtype=bool)
    planner_rows = np.flatnonzero(use_planner)
    if len(planner_rows):
        found = []
        for row, (res, path) in zip(planner_rows, _planner_paths(robot, s[planner_rows], g[planner_rows], steps,
                                                                 dict(planner or {}))):
            plans[int(row)] = res
            if path is not None:
                paths[row] = path
                before[int(row)] = float(np.linalg.norm(limits.diff(path[1:], path[:-1]), axis=1).sum())
                found.append(int(row))
        if found and sdf is not None and smooth_iterations > 0:
            rows = np.asarray(found)
            opts = dict(planner or {})
            fine = float(opts.get("resolution", 0.01)) / max(int(opts.get("verify", 10)), 1)
            best, at = smooth_certified(sdf, robot, unwrap_path(paths[rows], limits.cont_np),
                                        dataclasses.replace(penalty, iterations=smooth_iterations), fine)
            paths[rows], n_iter[rows], smoothed[rows] = limits.numpy(best), at, at > 0
    paths[:, 0], paths[:, -1] = s, g                    # exactly the caller's end points
    gs = np.full((len(paths), steps), np.nan, dtype=np.float32)
    if sdf is not None:
        with torch.no_grad():
            like = sdf.joint_limits
            gv = sdf(torch.as_tensor(paths.reshape(-1, s.shape[1]), dtype=like.dtype, device=like.device))
            gs = gv.reshape(len(paths), steps).cpu().numpy()
    seconds = time.perf_counter() - t0
    results = []
    for b, p in enumerate(paths):
        results.append(trajectory_result(
            robot, p, check_path(robot, p, density), g=gs[b], iterations=int(n_iter[b]), seconds=seconds,
            method=method if not use_planner[b] else ("planner+smooth" if sdf is not None else "planner"),
            straight_length=float(np.linalg.norm(limits.diff(g[b], s[b]))),
            initial_certified=bool(initial_certified[b]), init="planner" if use_planner[b] else "straight",
            planner=plans.get(b), smoothed=bool(smoothed[b]), length_before=before.get(b, float("nan"))))
    return results


def _through_frame_targets(sdf, start, goal, steps, method, *, robot, init, planner, penalty, tangent,
                           smooth_iterations, l_thres, density, layout, frame, frame_targets, margin, t0):
    """:func:`plan_trajectory` with end-effector targets at interior waypoints (its docs)."""
    from .frames import FrameTargets

    if frame is None or frame_targets is None:
        raise InputError("end-effector targets need both frame= (a site, body or geom) and frame_targets= "
                         "({waypoint index: target})")
    if np.ndim(start) != 1 or np.ndim(goal) != 1:
        raise InputError("frame_targets= plans one problem: start and goal must be single poses (K,)")
    sdf_l, robot_l = field_at_layout(sdf, robot, layout)
    robot_l = robot_l if sdf_l is None else field_robot(sdf_l, robot_l)
    robot_l = with_margin(robot_l, margin)
    steps = positive("steps", steps, integer=True)
    s = poses_within_limits(robot_l, start, "start")[0]
    g = poses_within_limits(robot_l, goal, "goal")[0]
    ft = FrameTargets(robot_l, frame, frame_targets, steps, "frame_targets")
    if ft.index.min() == 0 or ft.index.max() == steps - 1:
        raise InputError("frame_targets: the first and last waypoints are start and goal; target interior "
                         f"waypoints (1..{steps - 2})")
    straight = interpolate(robot_l, s, g, steps)
    fixed, ok = ft.snap(straight)
    if not ok.all():
        bad = int(ft.index[np.flatnonzero(~ok)[0]])
        raise InputError(f"frame_targets[{bad}]: no certified pose puts {frame!r} on its target")
    anchors = [0, *ft.index.tolist(), steps - 1]
    pieces, results = [fixed[:1]], []
    for a, b in zip(anchors[:-1], anchors[1:]):
        if b - a == 1:
            pieces.append(fixed[b:b + 1])
            continue
        sub = plan_trajectory(sdf_l, fixed[a], fixed[b], b - a + 1, method, robot=robot_l, init=init, planner=planner,
                              penalty=penalty, tangent=tangent, smooth_iterations=smooth_iterations, l_thres=l_thres,
                              density=density)
        results.append(sub)
        pieces.append(sub.path[1:])
    path = np.concatenate(pieces)
    path[ft.index] = fixed[ft.index]                    # exactly the certified IK poses
    gs = np.full(steps, np.nan, dtype=np.float32)
    if sdf_l is not None:
        with torch.no_grad():
            like = sdf_l.joint_limits
            gs = sdf_l(torch.as_tensor(path, dtype=like.dtype, device=like.device)).cpu().numpy()
    limits = Limits.of(robot_l)
    return trajectory_result(robot_l, path, check_path(robot_l, path, density), g=gs,
                             iterations=int(sum(r.iterations for r in results)), seconds=time.perf_counter() - t0,
                             method="+".join(sorted({r.method for r in results})) + "+frames" if results else "frames",
                             straight_length=float(np.linalg.norm(limits.diff(g, s))),
                             initial_certified=bool(check_path(robot_l, straight, density).certified),
                             init=init, planner=None, smoothed=any(r.smoothed for r in results),
                             length_before=float("nan"))


def _options(penalty: PenaltyOptions | None, tangent: TangentOptions | None, smooth_iterations: int,
             l_thres: float, density: int) -> tuple[PenaltyOptions, TangentOptions, int]:
    """The options of one call: explicit dataclasses, else defaults with ``l_thres`` and
    ``density``."""
    if penalty is not None and not isinstance(penalty, PenaltyOptions):
        raise InputTypeError(f"penalty must be a profrobot.optim.PenaltyOptions; got {type(penalty).__name__}")
    if tangent is not None and not isinstance(tangent, TangentOptions):
        raise InputTypeError(f"tangent must be a profrobot.optim.TangentOptions; got {type(tangent).__name__}")
    penalty = penalty if penalty is not None else PenaltyOptions(l_thres=l_thres, density=density)
    tangent = tangent if tangent is not None else TangentOptions(l_thres=l_thres)
    smooth_iterations = positive("smooth_iterations", smooth_iterations, integer=True, allow_zero=True)
    return penalty, tangent, smooth_iterations
