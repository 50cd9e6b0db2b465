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
between them (:func:`~profrobot.certification.check_path`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np
import torch

from ..joints import Limits
from ..labels import interpolate
from ..robot import Robot
from .adam import BatchedAdam
from ..field.identity import field_robot
from ..validate import finite, positive, poses_within_limits
from ..certification import PathCheck, check_path, path_free_at
from ..errors import InputError

Method = Literal["penalty", "tangent"]
GoalNorm = Literal["l1", "l2"]
Init = Literal["auto", "straight", "planner"]
METHODS: tuple[str, ...] = get_args(Method)
INITS: tuple[str, ...] = get_args(Init)


@dataclass
class TrajectoryResult:
    """A planned path and the exact labeller's verdict on it.

    Attributes:
        path: (S, K) float64 waypoints, radians / metres, ``path[0]`` = start, ``path[-1]`` = goal.
        free: the whole path is free at the dense check (waypoints and ``density``× finer samples).
        waypoint_collides: (S,) bool; segment_collides: (S−1,) bool (segment i: waypoints i, i+1).
        g: (S,) float32, the field along the path.
        length: Σ‖θ_{i+1} − θ_i‖ (radians, continuous joints the short way); straight_length: the
            same for the straight SO(2) interpolation; relative_length = length / straight_length.
        iterations: optimiser steps (penalty: Adam steps; tangent: walk steps).
        seconds: wall time of the batched call that produced it, shared by its problems.
    """

    path: np.ndarray
    free: bool
    waypoint_collides: np.ndarray
    segment_collides: np.ndarray
    g: np.ndarray
    method: str
    iterations: int
    length: float
    straight_length: float
    seconds: float
    check: PathCheck = field(repr=False)
    initial_free: bool = False
    init: str = "straight"
    planner: object = field(default=None, repr=False)   # the PathResult when init used the planner
    smoothed: bool = False
    length_before: float = float("nan")                 # the resampled planner path's length

    @property
    def relative_length(self) -> float:
        return self.length / self.straight_length if self.straight_length > 0 else 1.0

    @property
    def colliding_waypoints(self) -> np.ndarray:
        return np.flatnonzero(self.waypoint_collides)

    @property
    def colliding_segments(self) -> np.ndarray:
        return np.flatnonzero(self.segment_collides)

    def summary(self) -> str:
        where = "" if self.free else (f": {len(self.colliding_segments)} colliding segment(s), "
                                      f"first at {self.colliding_segments[:1].tolist()}")
        return (f"{self.method} path of {len(self.path)} waypoints, {'free' if self.free else 'COLLIDES'}{where}; "
                f"length {self.relative_length:.2f}× the straight interpolation, {self.iterations} iterations")


def _unwrap(path: np.ndarray, cont: np.ndarray) -> np.ndarray:
    """Continuous joints unwrapped along the steps axis of (..., S, K), so paths are continuous."""
    out = path.copy()
    if cont.any():
        out[..., cont] = np.unwrap(path[..., cont], axis=-2)
    return out


def _penalty(sdf, limits: Limits, robot: Robot, paths: np.ndarray, l_thres: float, gamma1: float, gamma2: float,
             lr: float, iterations: int, check_every: int, density: int, refine_step: float, gamma3: float,
             midpoints: bool) -> np.ndarray:
    """Optimises (B, S, K) unwrapped paths in place of their interior waypoints; a problem stops
    once the exact labeller finds its whole path free at the dense check. A problem whose
    waypoints all meet the threshold while the labeller still finds a collision has its threshold
    lowered by ``refine_step``. Returns (B,) steps."""
    like = sdf.joint_limits
    B, S, K = paths.shape
    full = torch.as_tensor(paths, dtype=like.dtype, device=like.device).clone()
    x = full[:, 1:-1].reshape(B, -1).clone()            # (B, (S−2)·K): one Adam row per problem
    x0 = x.clone()
    opt = BatchedAdam(x.shape, lr, x)
    steps = np.zeros(B, dtype=np.int64)
    active = torch.arange(B, device=x.device)
    thres = torch.full((B,), l_thres, dtype=x.dtype, device=x.device)
    energy0 = (full[:, 1:] - full[:, :-1]).pow(2).sum(2).mean(1).clamp(min=1e-12)   # the straight path's
    g_max = torch.full((B,), float("inf"), dtype=x.dtype, device=x.device)
    for it in range(iterations + 1):
        if it % check_every == 0 or it == iterations:
            rows = active.cpu().numpy()
            cur = full[rows].clone()
            cur[:, 1:-1] = x[active].reshape(len(rows), S - 2, K)
            # the cheap test (no distances) first; only paths that pass it get the strict one
            # (clearance, as in the final verdict), which costs ~15x more per pose
            done = np.array([check_path(robot, q, density, clearance=0.0).free and check_path(robot, q, density).free
                             for q in limits.numpy(cur.cpu().numpy())], dtype=bool)
            # the field is satisfied but the labeller is not: ask that problem for a deeper margin
            stuck = active[torch.as_tensor(~done, device=x.device) & (g_max[active] <= thres[active])]
            thres[stuck] -= refine_step
            active = active[torch.as_tensor(~done, device=x.device)]
        if len(active) == 0 or it == iterations:
            break
        xa = x[active].detach().requires_grad_(True)
        inner = xa.reshape(len(active), S - 2, K)
        path = torch.cat([full[active, :1], inner, full[active, -1:]], dim=1)
        g = sdf(limits.wrap(inner).reshape(-1, K)).reshape(len(active), S - 2)
        g_max[active] = g.detach().max(1).values
        l_sdf = torch.relu(g - thres[active, None]).mean(1)
        seg = path[:, 1:] - path[:, :-1]
        tv = seg.norm(dim=2).mean(1)
        loss = gamma1 * l_sdf + gamma2 * tv
        if midpoints:   # the field at segment midpoints too: waypoints alone let a path hop an obstacle
            gm = sdf(limits.wrap(0.5 * (path[:, 1:] + path[:, :-1])).reshape(-1, K)).reshape(len(active), S - 1)
            g_max[active] = torch.maximum(g_max[active], gm.detach().max(1).values)
            loss = loss + gamma1 * torch.relu(gm - thres[active, None]).mean(1)
        if gamma3 > 0:  # path energy: keeps waypoints evenly spaced (TV alone lets one segment stretch)
            loss = loss + gamma3 * (seg.pow(2).sum(2).mean(1) / energy0[active])
        loss = loss.sum()                               # problems independent: per-row gradients
        (grad,) = torch.autograd.grad(loss, xa)
        opt.step(x, active, grad)
        limits.clamp_(x.view(B, S - 2, K))
        steps[active.cpu().numpy()] += 1
    # the float32 displacement on the float64 path: untouched waypoints stay bit for bit
    paths[:, 1:-1] += (x - x0).reshape(B, S - 2, K).cpu().numpy().astype(np.float64)
    return steps


def _smooth(sdf, limits: Limits, robot: Robot, paths: np.ndarray, l_thres: float, gamma1: float, gamma2: float,
            gamma3: float, lr: float, iterations: int, check_every: int, density: int,
            verify_resolution: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """Shortens (B, S, K) unwrapped, certified-free paths with the field.

    Adam on the interior waypoints of γ1·mean ReLU(g − l_thres) + γ2·TV (+ γ3·energy, which keeps
    waypoints evenly spaced); every ``check_every`` steps each problem's current path is checked
    by the exact labeller (dense check) and kept when it is free and shorter than the best so far.
    The input paths are the first "best", so certification is never lost and length never grows.
    Returns (best paths (B, S, K) float64, (B,) the step at which each best was taken).
    """
    like = sdf.joint_limits
    B, S, K = paths.shape
    best = paths.copy()
    best_len = np.linalg.norm(np.diff(paths, axis=1), axis=2).sum(1)
    best_at = np.zeros(B, dtype=np.int64)
    full = torch.as_tensor(paths, dtype=like.dtype, device=like.device)
    x0 = full[:, 1:-1].reshape(B, -1).clone()
    x = x0.clone()
    opt = BatchedAdam(x.shape, lr, x)
    rows = torch.arange(B, device=x.device)
    energy0 = (full[:, 1:] - full[:, :-1]).pow(2).sum(2).mean(1).clamp(min=1e-12)
    for it in range(1, iterations + 1):
        xa = x.detach().requires_grad_(True)
        inner = xa.reshape(B, S - 2, K)
        path = torch.cat([full[:, :1], inner, full[:, -1:]], dim=1)
        g = sdf(limits.wrap(inner).reshape(-1, K)).reshape(B, S - 2)
        seg = path[:, 1:] - path[:, :-1]
        loss = gamma1 * torch.relu(g - l_thres).mean(1) + gamma2 * seg.norm(dim=2).mean(1)
        if gamma3 > 0:
            loss = loss + gamma3 * (seg.pow(2).sum(2).mean(1) / energy0)
        (grad,) = torch.autograd.grad(loss.sum(), xa)
        opt.step(x, rows, grad)
        limits.clamp_(x.view(B, S - 2, K))
        if it % check_every == 0 or it == iterations:
            cur = paths.copy()
            cur[:, 1:-1] += (x - x0).reshape(B, S - 2, K).cpu().numpy().astype(np.float64)
            length = np.linalg.norm(np.diff(cur, axis=1), axis=2).sum(1)
            for b in np.flatnonzero(length < best_len - 1e-9):
                q = limits.numpy(cur[b:b + 1])[0]
                # the waypoint-relative dense check and the planner's own guarantee (no joint moves
                # more than `verify_resolution` between checked poses): a smoothed segment may be
                # long, and density alone would sample it more coarsely than the planner did
                if (check_path(robot, q, density).free
                        and path_free_at(robot, q, verify_resolution, clearance=0.0)):
                    best[b], best_len[b], best_at[b] = cur[b], length[b], it
    return best, best_at


def _planner_paths(robot: Robot, s: np.ndarray, g: np.ndarray, steps: int, options: dict) -> list:
    """A certified planner path per problem, resampled to ``steps`` waypoints (None when the
    planner found none, or needs more waypoints than ``steps``)."""
    from ..planning import plan_path, resample_path

    out = []
    for b in range(len(s)):
        res = plan_path(robot, s[b], g[b], **{"seed": b, **options})
        path = resample_path(robot, res.path, steps) if res.found and len(res.path) <= steps else None
        out.append((res, path))
    return out


def _tangent(sdf, limits: Limits, starts: np.ndarray, goals: np.ndarray, steps: int, l_thres: float, delta: float,
             band: float, max_iters: int, tol: float, goal_norm: GoalNorm) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 1, batched over B problems: θ ← θ − δ·D, D the L1 goal gradient G (per-joint
    steps clipped so that no joint overshoots the goal), projected onto the tangent plane of ∇g
    where g ≥ l_thres − band and the step would raise g; poses past the threshold take a
    Gauss-Newton step back to g = l_thres. Returns (B, steps, K) unwrapped paths resampled by arc
    length from each walk, and the walk lengths (B,)."""
    like = sdf.joint_limits
    B, K = starts.shape
    goal_np = starts + limits.diff(goals, starts)       # unwrapped goal: the short way round
    theta = torch.as_tensor(starts, dtype=like.dtype, device=like.device).clone()
    goal = torch.as_tensor(goal_np, dtype=like.dtype, device=like.device)
    walks = [theta.cpu().numpy().copy()]
    n_iter = np.zeros(B, dtype=np.int64)
    active = torch.ones(B, dtype=torch.bool, device=theta.device)
    for _ in range(max_iters):
        d = theta - goal
        active &= d.abs().sum(1) >= tol
        if not active.any():
            break
        x = theta.detach().requires_grad_(True)
        g = sdf(limits.wrap(x))
        (grad_g,) = torch.autograd.grad(g.sum(), x)
        with torch.no_grad():
            norm = grad_g.norm(dim=1, keepdim=True).clamp(min=1e-8)
            n = grad_g / norm
            if goal_norm == "l1":   # Algorithm 1: ∂‖θ − θ_end‖₁, each joint clipped so as not to overshoot
                G = torch.sign(d) * torch.clamp(d.abs() / delta, max=1.0)
            else:                   # ∂‖θ − θ_end‖₂: straight towards the goal in free space
                dist = d.norm(dim=1, keepdim=True)
                G = d / dist.clamp(min=1e-12) * torch.clamp(dist / delta, max=1.0)
            along = (n * G).sum(1, keepdim=True)
            project = (g[:, None] >= l_thres - band) & (along < 0)
            D = torch.where(project, G - along * n, G)
            back = torch.relu(g - l_thres)[:, None] * grad_g / norm**2    # return to the g = l_thres surface
            step = delta * D + back
            theta = torch.where(active[:, None], theta - step, theta)
            limits.clamp_(theta)
        n_iter += active.cpu().numpy()
        walks.append(theta.cpu().numpy().copy())
    walk = np.stack(walks, axis=1)                      # (B, T, K)
    walk = np.concatenate([walk, goal_np[:, None]], axis=1)  # end exactly at the goal
    out = np.empty((B, steps, K))
    for b in range(B):
        seg = np.linalg.norm(np.diff(walk[b], axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        u = np.linspace(0.0, s[-1], steps)
        out[b] = np.stack([np.interp(u, s, walk[b, :, k]) for k in range(K)], axis=1)
        out[b, 0], out[b, -1] = walk[b, 0], goal_np[b]
    return out, n_iter


def plan_trajectory(sdf, start, goal, steps: int = 100, method: Method = "penalty", *, robot: Robot | None = None,
                    init: Init = "auto", planner: dict | None = None, smooth_iters: int = 300,
                    l_thres: float = -0.1, gamma1: float = 5.0, gamma2: float = 1.0, lr: float = 0.01,
                    iterations: int = 500, check_every: int = 10, density: int = 10, delta: float = 0.01,
                    band: float = 0.05, tangent_iters: int = 3000, tol: float = 1e-4, goal_norm: GoalNorm = "l1",
                    refine_step: float = 0.05, gamma3: float = 0.0, midpoints: bool = False):
    """A collision-aware path from ``start`` to ``goal`` (K,) (radians / metres, within the joint
    limits), with ``steps`` waypoints including both ends. Batches: (B, K) start and goal give a
    list of B results, optimised together.

    ``init``: ``"straight"`` optimises the straight SO(2) interpolation with ``method``;
    ``"planner"`` starts every problem from :func:`profrobot.plan_path` (``planner``: its
    options, e.g. ``dict(resolution=0.01, max_time=10.0)``), resampled to ``steps`` waypoints and
    smoothed with the field for ``smooth_iters`` Adam steps (γ1·mean L_SDF + γ2·TV, the shortest
    certified iterate kept; the certified planner path itself if none is shorter); ``"auto"``
    (default) does ``"straight"`` where the straight path is free at the dense check and
    ``"planner"`` where it collides. ``sdf=None`` (``robot`` required): exact planning and
    shortcutting only.

    ``method="penalty"``: Adam (``lr``, at most ``iterations`` steps) on γ1·mean ReLU(g − l_thres) +
    γ2·TV over the interior waypoints; each problem stops once its path is free at the dense check
    (the threshold of a problem whose waypoints meet it while the path still collides is lowered
    by ``refine_step``; 0 turns that off). Beyond the paper: ``midpoints`` adds the penalty at
    segment midpoints, ``gamma3`` weighs the path energy mean ‖θ_{i+1} − θ_i‖² (relative to the
    straight path's), which keeps waypoints evenly spaced so that no segment hops an obstacle.
    ``method="tangent"``: Algorithm 1 with step ``delta`` (radians), at most ``tangent_iters`` steps;
    ``goal_norm`` "l1" (the paper's L1 goal distance) or "l2" (straight lines in free space).
    ``density``: the dense check samples each segment this many times finer. ``robot``: the
    labeller's robot (default: the field's own).
    """
    t0 = time.perf_counter()
    if sdf is None:
        if not isinstance(robot, Robot):
            raise InputError("plan_trajectory(sdf=None) plans with the exact labeller alone and needs robot=")
    else:
        robot = field_robot(sdf, robot)
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}; got {method!r}")
    if init not in INITS:
        raise InputError(f"init must be one of {INITS}; got {init!r}")
    if sdf is None and init == "straight":
        raise InputError("init='straight' optimises with the field; with sdf=None use init='auto' or 'planner'")
    if goal_norm not in get_args(GoalNorm):
        raise InputError(f"goal_norm must be 'l1' or 'l2'; got {goal_norm!r}")
    if planner is not None and not isinstance(planner, dict):
        raise TypeError(f"planner must be a dict of plan_path options; got {type(planner).__name__}")
    single = np.ndim(start) == 1 and np.ndim(goal) == 1
    s = poses_within_limits(robot, start, "start")
    g = poses_within_limits(robot, goal, "goal")
    if s.shape != g.shape:
        raise InputError(f"start and goal must have the same shape; got {s.shape} and {g.shape}")
    steps = positive("steps", steps, integer=True)
    if steps < 3:
        raise InputError(f"steps must be >= 3 (the end points are fixed); got {steps}")
    l_thres = finite("l_thres", l_thres)
    gamma1, gamma2 = positive("gamma1", gamma1, allow_zero=True), positive("gamma2", gamma2, allow_zero=True)
    lr, delta = positive("lr", lr), positive("delta", delta)
    iterations = positive("iterations", iterations, integer=True, allow_zero=True)
    smooth_iters = positive("smooth_iters", smooth_iters, integer=True, allow_zero=True)
    check_every = positive("check_every", check_every, integer=True)
    density = positive("density", density, integer=True)
    band, tol = positive("band", band, allow_zero=True), positive("tol", tol)
    refine_step = positive("refine_step", refine_step, allow_zero=True)
    gamma3 = positive("gamma3", gamma3, allow_zero=True)
    tangent_iters = positive("tangent_iters", tangent_iters, integer=True, allow_zero=True)

    limits = Limits.of(robot, sdf.joint_limits if sdf is not None else None)
    straight = interpolate(robot, s, g, steps)          # (B, S, K): SO(2), from the Rust core
    initial_free = np.array([check_path(robot, p, density, clearance=0.0).free for p in straight], dtype=bool)
    use_planner = np.ones(len(s), dtype=bool) if init == "planner" else (
        ~initial_free if init == "auto" else np.zeros(len(s), dtype=bool))
    paths = limits.numpy(straight.copy())
    n_iter = np.zeros(len(s), dtype=np.int64)
    straight_rows = np.flatnonzero(~use_planner)
    if len(straight_rows) and sdf is not None:         # without a field a free straight path stays as it is
        ss, gg = s[straight_rows], g[straight_rows]
        if method == "penalty":
            sub = _unwrap(straight[straight_rows], limits.cont_np)
            it = _penalty(sdf, limits, robot, sub, l_thres, gamma1, gamma2, lr, iterations, check_every, density,
                          refine_step, gamma3, bool(midpoints))
        else:
            sub, it = _tangent(sdf, limits, ss, gg, steps, l_thres, delta, band, tangent_iters, tol, goal_norm)
        paths[straight_rows], n_iter[straight_rows] = limits.numpy(sub), it
    plans: dict[int, object] = {}
    before: dict[int, float] = {}
    smoothed = np.zeros(len(s), dtype=bool)
    planner_rows = np.flatnonzero(use_planner)
    if len(planner_rows):
        found = []
        for b, (res, path) in zip(planner_rows, _planner_paths(robot, s[planner_rows], g[planner_rows], steps,
                                                               dict(planner or {}))):
            plans[int(b)] = res
            if path is not None:
                paths[b] = path
                before[int(b)] = float(np.linalg.norm(limits.diff(path[1:], path[:-1]), axis=1).sum())
                found.append(int(b))
        if found and sdf is not None and smooth_iters > 0:
            rows = np.asarray(found)
            opts = dict(planner or {})
            fine = float(opts.get("resolution", 0.01)) / max(int(opts.get("verify", 10)), 1)
            best, at = _smooth(sdf, limits, robot, _unwrap(paths[rows], limits.cont_np), l_thres, gamma1, gamma2,
                               gamma3, lr, smooth_iters, check_every, density, fine)
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
        chk = check_path(robot, p, density)
        results.append(TrajectoryResult(
            path=p, free=chk.free, waypoint_collides=chk.waypoint_collides, segment_collides=chk.segment_collides,
            g=gs[b], method=method if not use_planner[b] else ("planner+smooth" if sdf is not None else "planner"),
            iterations=int(n_iter[b]),
            length=float(np.linalg.norm(limits.diff(p[1:], p[:-1]), axis=1).sum()),
            straight_length=float(np.linalg.norm(limits.diff(g[b], s[b]))), seconds=seconds, check=chk,
            initial_free=bool(initial_free[b]), init="planner" if use_planner[b] else "straight",
            planner=plans.get(b), smoothed=bool(smoothed[b]), length_before=before.get(b, float("nan"))))
    return results[0] if single else results
