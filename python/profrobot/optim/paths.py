"""The two local path optimisers on the learned field, batched over B problems, each with its
knobs in one options dataclass (what :func:`profrobot.plan_trajectory` and the inverse problems
pass around):

- :func:`penalty_descent` (:class:`PenaltyOptions`): Adam on the interior waypoints of
  γ1·mean ReLU(g − l_thres) + γ2·TV (+ γ3·energy), each problem stopping once the exact labeller
  certifies its whole path (:func:`profrobot.exact.certification.check_path`);
- :func:`smooth_certified` (the same options): shortens already-certified paths, keeping the
  shortest iterate that is still certified, so certification is never lost;
- :func:`tangent_walk` (:class:`TangentOptions`): the paper's Algorithm 1.

Paths are (B, S, K) float64, radians / metres, continuous joints unwrapped along S
(:func:`unwrap_path`); the end points never move.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import torch

from ..robot.angles import unwrap
from ..exact.certification import check_path, path_free_at
from ..kinematics.limits import LIMIT_INSET, Limits
from ..field.identity import Field
from ..robot.robot import Robot
from ..robot.gate import finite, positive
from ..errors import InputError
from .adam import BatchedAdam

__all__ = ["PenaltyOptions", "TangentOptions", "penalty_descent", "smooth_certified", "tangent_walk", "unwrap_path"]

GoalNorm = Literal["l1", "l2"]


@dataclass(frozen=True)
class PenaltyOptions:
    """Knobs of :func:`penalty_descent` and :func:`smooth_certified`.

    Attributes:
        l_thres: the field threshold of the penalty ReLU(g − l_thres).
        gamma1: weight of mean ReLU(g − l_thres) over the interior waypoints.
        gamma2: weight of TV = mean ‖θ_{i+1} − θ_i‖.
        gamma3: weight of the path energy mean ‖θ_{i+1} − θ_i‖² relative to the start path's
            (beyond the paper: keeps waypoints evenly spaced so no segment hops an obstacle).
        lr: Adam's learning rate (radians).
        iterations: at most this many Adam steps.
        check_every: the exact labeller checks every this many steps.
        density: the sampled check's samples per segment (``check_path(..., method="sampled")``);
            the paths here are certified continuously, which needs none.
        refine_step: a problem whose waypoints all meet the threshold while the labeller still
            finds a collision has its threshold lowered by this much (0: off).
        midpoints: the penalty at segment midpoints too (beyond the paper).
    """

    l_thres: float = -0.1
    gamma1: float = 5.0
    gamma2: float = 1.0
    gamma3: float = 0.0
    lr: float = 0.01
    iterations: int = 500
    check_every: int = 10
    density: int = 10
    refine_step: float = 0.05
    midpoints: bool = False

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)
        set_("l_thres", finite("l_thres", self.l_thres))
        for k in ("gamma1", "gamma2", "gamma3", "refine_step"):
            set_(k, positive(k, getattr(self, k), allow_zero=True))
        set_("lr", positive("lr", self.lr))
        set_("iterations", positive("iterations", self.iterations, integer=True, allow_zero=True))
        set_("check_every", positive("check_every", self.check_every, integer=True))
        set_("density", positive("density", self.density, integer=True))
        set_("midpoints", bool(self.midpoints))


@dataclass(frozen=True)
class TangentOptions:
    """Knobs of :func:`tangent_walk` (Algorithm 1).

    Attributes:
        l_thres: the field threshold the walk keeps to.
        delta: step length (radians).
        band: the projection starts ``band`` below the threshold.
        iterations: at most this many walk steps.
        tol: the walk ends within this L1 distance of the goal.
        goal_norm: "l1" (the paper's L1 goal distance) or "l2" (straight lines in free space).
    """

    l_thres: float = -0.1
    delta: float = 0.01
    band: float = 0.05
    iterations: int = 3000
    tol: float = 1e-4
    goal_norm: GoalNorm = "l1"

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)
        set_("l_thres", finite("l_thres", self.l_thres))
        set_("delta", positive("delta", self.delta))
        set_("band", positive("band", self.band, allow_zero=True))
        set_("iterations", positive("iterations", self.iterations, integer=True, allow_zero=True))
        set_("tol", positive("tol", self.tol))
        if self.goal_norm not in get_args(GoalNorm):
            raise InputError(f"goal_norm must be 'l1' or 'l2'; got {self.goal_norm!r}")


def unwrap_path(path: np.ndarray, continuous: np.ndarray) -> np.ndarray:
    """(..., S, K) with continuous joints (``continuous`` (K,) bool) unwrapped along the steps
    axis (:func:`profrobot.robot.angles.unwrap`), so that consecutive waypoints differ by the short arc,
    as :func:`profrobot.interpolate` moves them, and paths are continuous."""
    out = np.array(path, dtype=np.float64, copy=True)
    cont = np.asarray(continuous, dtype=bool)
    if cont.any():
        out[..., cont] = unwrap(out[..., cont], axis=-2)
    return out


def penalty_descent(sdf: Field, robot: Robot, paths: np.ndarray, options: PenaltyOptions | None = None) -> np.ndarray:
    """Optimises ``paths`` (B, S, K) unwrapped, in place, on their interior waypoints; a problem
    stops once the exact labeller certifies its whole path (continuously). A problem whose
    waypoints all meet the threshold while the labeller still finds a collision has its threshold
    lowered by ``options.refine_step``. Returns (B,) int, the Adam steps each problem took."""
    o = options if options is not None else PenaltyOptions()
    l_thres, gamma1, gamma2, gamma3, lr = o.l_thres, o.gamma1, o.gamma2, o.gamma3, o.lr
    iterations, check_every, density, refine_step, midpoints = o.iterations, o.check_every, o.density, o.refine_step, o.midpoints
    like = sdf.joint_limits
    limits = Limits.of(robot, like)
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
            done = np.array([check_path(robot, q, density).certified for q in limits.numpy(cur.cpu().numpy())],
                            dtype=bool)
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
        limits.clamp_(x.view(B, S - 2, K), LIMIT_INSET)
        steps[active.cpu().numpy()] += 1
    # the float32 displacement on the float64 path: untouched waypoints stay bit for bit
    paths[:, 1:-1] += (x - x0).reshape(B, S - 2, K).cpu().numpy().astype(np.float64)
    return steps


def smooth_certified(sdf: Field, robot: Robot, paths: np.ndarray, options: PenaltyOptions | None = None,
                     verify_resolution: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """Shortens ``paths`` (B, S, K), unwrapped and certified, with the field.

    Adam on the interior waypoints of γ1·mean ReLU(g − l_thres) + γ2·TV (+ γ3·energy, which keeps
    waypoints evenly spaced); every ``check_every`` steps each problem's current path is checked
    by the exact labeller (continuous certificate) and kept when it is free and shorter than the best so far.
    The input paths are the first "best", so certification is never lost and length never grows.
    Uses ``options``' l_thres, gamma1–3, lr, iterations, check_every and density.
    Returns (best paths (B, S, K) float64, (B,) the step at which each best was taken).
    """
    o = options if options is not None else PenaltyOptions()
    l_thres, gamma1, gamma2, gamma3, lr = o.l_thres, o.gamma1, o.gamma2, o.gamma3, o.lr
    iterations, check_every, density = o.iterations, o.check_every, o.density
    like = sdf.joint_limits
    limits = Limits.of(robot, like)
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
        limits.clamp_(x.view(B, S - 2, K), LIMIT_INSET)
        if it % check_every == 0 or it == iterations:
            cur = paths.copy()
            cur[:, 1:-1] += (x - x0).reshape(B, S - 2, K).cpu().numpy().astype(np.float64)
            length = np.linalg.norm(np.diff(cur, axis=1), axis=2).sum(1)
            for b in np.flatnonzero(length < best_len - 1e-9):
                q = limits.numpy(cur[b:b + 1])[0]
                # the waypoint-relative dense check and the planner's own guarantee (no joint moves
                # more than `verify_resolution` between checked poses): a smoothed segment may be
                # long, and density alone would sample it more coarsely than the planner did
                if check_path(robot, q, density).certified and path_free_at(robot, q, verify_resolution):
                    best[b], best_len[b], best_at[b] = cur[b], length[b], it
    return best, best_at


def tangent_walk(sdf: Field, robot: Robot, starts: np.ndarray, goals: np.ndarray, steps: int,
                 options: TangentOptions | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 1, batched over B problems: θ ← θ − δ·D, D the L1 goal gradient G (per-joint
    steps clipped so that no joint overshoots the goal), projected onto the tangent plane of ∇g
    where g ≥ l_thres − band and the step would raise g; poses past the threshold take a
    Gauss-Newton step back to g = l_thres. Returns (B, steps, K) unwrapped paths resampled by arc
    length from each walk, and the walk lengths (B,). ``starts``, ``goals``: (B, K)."""
    o = options if options is not None else TangentOptions()
    l_thres, delta, band, max_iters, tol, goal_norm = o.l_thres, o.delta, o.band, o.iterations, o.tol, o.goal_norm
    like = sdf.joint_limits
    limits = Limits.of(robot, like)
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
            limits.clamp_(theta, LIMIT_INSET)
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
