"""Collision resolution (paper §4.2): push colliding poses to g(θ) ≤ l_thres with Adam on the
fixed field, all poses in one batch, then certify each result with the exact labeller."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ..robot import Robot
from .adam import BatchedAdam
from ..joints import LIMIT_INSET, Limits
from ..field.identity import field_robot
from ..field.layout import field_at_layout
from ..validate import finite, positive, poses_within_limits
from ..certification import certified_summary, certify_poses, failures_of
from ..deprecation import renamed_arguments


@dataclass
class ResolveResult:
    """Outcome of :func:`resolve` for B poses.

    Attributes:
        poses: (B, K) float64 resolved poses, radians / metres, within the joint limits.
        iterations: (B,) int, Adam steps each pose took (0: it already met the threshold).
        delta: (B,) float64, ‖θ_out − θ_in‖₂ in radians (continuous joints the short way round).
        certified: (B,) bool, the returned pose is certified free (:mod:`profrobot.certification`).
        g: (B,) float32, the field at the returned pose.
        reached: (B,) bool, the pose met its (final) field threshold within the budget.
        threshold: (B,) float64, the last threshold each pose was driven to (l_thres, or lower
            after refinement rounds).
        seconds: wall time of the whole call (optimisation + certification).
    """

    poses: np.ndarray
    iterations: np.ndarray
    delta: np.ndarray
    certified: np.ndarray
    g: np.ndarray
    reached: np.ndarray
    threshold: np.ndarray
    seconds: float
    rounds: int = 0
    history: list = field(default_factory=list, repr=False)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def failures(self) -> np.ndarray:
        """Indices of poses that are not certified free."""
        return failures_of(self.certified)

    def summary(self) -> str:
        n = len(self)
        return (f"{n} poses: {certified_summary(self.certified)}, mean iterations {self.iterations.mean():.2f}, "
                f"mean Δθ {self.delta.mean():.3f} rad, {self.seconds:.2f} s "
                f"({self.rounds} refinement round{'s' * (self.rounds != 1)})")


def _descend(sdf, theta: torch.Tensor, rows: torch.Tensor, thresholds: torch.Tensor, opt: BatchedAdam,
             limits: Limits, budget: int, iterations: torch.Tensor, g_out: torch.Tensor) -> None:
    """Adam on g for poses ``rows`` until each meets g ≤ its threshold (then it is frozen) or
    ``budget`` steps; updates θ, iteration counts and g in place."""
    active = rows
    for it in range(budget + 1):
        if len(active) == 0:
            break
        x = theta[active].detach().requires_grad_(True)
        g = sdf(x)
        g_out[active] = g.detach()
        todo = g.detach() > thresholds[active]
        if it == budget or not todo.any():
            break
        (grad,) = torch.autograd.grad(g.sum(), x)  # per-pose gradients: poses are independent
        stepped = active[todo]
        opt.step(theta, stepped, grad[todo])
        # joint limits respected after every step, LIMIT_INSET inside them for the joints it moves (a
        # pose on a limit may touch: clearance 0, never certified); poses not stepped stay as they are
        theta[stepped] = limits.clamp_or_wrap(theta[stepped], LIMIT_INSET)
        iterations[active[todo]] += 1
        active = active[todo]


def certify_and_continue(robot: Robot, certified: np.ndarray, again: Callable[[np.ndarray, float], np.ndarray], *,
                         l_thres: float, step: float, rounds: int, history: list | None = None) -> int:
    """The paper's certify-and-continue, the one loop every field-driven answer runs: while some
    of B poses are not certified (``certified`` (B,) bool, updated in place), lower their field
    threshold by ``step`` per round (``l_thres − r·step`` in round r: the field called them free
    enough, the labeller did not) and ``again(rows, threshold)`` continues the descent of those
    rows (its optimiser moments restarted) and returns their new poses (len(rows), K), which are
    certified again. At most ``rounds`` rounds; returns how many ran. ``history`` (a list) gets one
    dict per round: round, threshold, certified count."""
    r = 0
    while r < rounds and not certified.all():
        r += 1
        bad = np.flatnonzero(~certified)
        threshold = l_thres - r * step
        certified[bad] = certify_poses(robot, again(bad, threshold))
        if history is not None:
            history.append(dict(round=r, threshold=threshold, certified=int(certified.sum())))
    return r


@renamed_arguments(max_iters="iterations", refine_iters="refine_iterations")
def resolve(sdf, poses, l_thres: float = -0.1, lr: float = 0.01, iterations: int = 1000, *,
            robot: Robot | None = None, refine: bool = True, refine_rounds: int = 4,
            refine_step: float = 0.1, refine_iterations: int | None = None, scene=None) -> ResolveResult:
    """Resolve collisions of ``poses`` (B, K) (radians / metres, within joint limits) with the
    learned field ``sdf``: Adam (``lr``) on g(θ), all poses in one batch, each pose frozen as soon
    as g ≤ ``l_thres`` (at most ``iterations`` steps); joint limits are enforced after each step
    (clamped; continuous hinges wrapped). Every result is then labelled by the exact labeller
    (``certified``).

    ``refine`` (default): poses the labeller still finds colliding continue with the threshold
    lowered by ``refine_step`` per round, for up to ``refine_rounds`` rounds of ``refine_iterations``
    steps (default ``iterations``) each, until certified. Poses left colliding are reported in
    ``result.failures``, never hidden. ``robot``: the labeller's robot (default: the bundled
    scene the field was trained on). ``scene``: for a field of a family of scenes
    (:mod:`profrobot.family`), the layout δ to work at; answers are certified at exactly that layout.
    """
    start = time.perf_counter()
    sdf, robot = field_at_layout(sdf, robot, scene)
    robot = field_robot(sdf, robot)
    q0 = poses_within_limits(robot, poses)
    l_thres = finite("l_thres", l_thres)
    lr = positive("lr", lr)
    iterations = positive("iterations", iterations, integer=True, allow_zero=True)
    refine_rounds = positive("refine_rounds", refine_rounds, integer=True, allow_zero=True)
    refine_step = positive("refine_step", refine_step)
    refine_iterations = iterations if refine_iterations is None else positive("refine_iterations", refine_iterations, integer=True)

    like = sdf.joint_limits
    theta = torch.as_tensor(q0, dtype=like.dtype, device=like.device).clone()
    B, K = theta.shape
    limits = Limits.of(robot, theta)
    opt = BatchedAdam((B, K), lr, theta)
    thresholds = torch.full((B,), l_thres, dtype=theta.dtype, device=theta.device)
    steps_taken = torch.zeros(B, dtype=torch.long, device=theta.device)
    g = torch.empty(B, dtype=theta.dtype, device=theta.device)
    rows = torch.arange(B, device=theta.device)

    theta_in = theta.clone()

    def result(sel=slice(None)) -> np.ndarray:
        # the input plus the float32 displacement: a pose that never moved comes back bit for bit
        moved = (theta[sel] - theta_in[sel]).cpu().numpy().astype(np.float64)
        return limits.numpy(q0[sel] + moved)

    _descend(sdf, theta, rows, thresholds, opt, limits, iterations, steps_taken, g)
    out = result()
    certified = certify_poses(robot, out)
    history = [dict(round=0, threshold=l_thres, certified=int(certified.sum()))]

    def again(bad: np.ndarray, threshold: float) -> np.ndarray:
        rows_t = torch.as_tensor(bad, device=theta.device)
        thresholds[rows_t] = threshold
        opt.reset(rows_t)
        _descend(sdf, theta, rows_t, thresholds, opt, limits, refine_iterations, steps_taken, g)
        out[bad] = result(bad)
        return out[bad]

    rounds = certify_and_continue(robot, certified, again, l_thres=l_thres, step=refine_step,
                                  rounds=refine_rounds if refine else 0, history=history)

    g_np = g.cpu().numpy()
    thr = thresholds.cpu().numpy().astype(np.float64)
    return ResolveResult(poses=out, iterations=steps_taken.cpu().numpy(),
                         delta=np.linalg.norm(limits.diff(out, q0), axis=1), certified=certified,
                         g=g_np, reached=g_np <= thr, threshold=thr,
                         seconds=time.perf_counter() - start, rounds=rounds, history=history)
