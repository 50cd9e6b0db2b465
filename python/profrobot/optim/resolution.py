"""Collision resolution: move each colliding pose as little as possible to a pose the exact
labeller certifies free, steered by the learned field g (paper §4.2), all poses in one batch.

Two field steps (``method``):

- ``"project"`` (default): Newton steps on the constraint, each the exact Euclidean projection of
  the iterate θₖ onto {θ : g(θₖ) + ∇g(θₖ)·(θ − θₖ) ≤ l_thres} intersected with the joint-limit
  box (inside the box: the step −(g − l_thres)/‖∇g‖² ∇g; at its faces one scalar multiplier,
  found by bisection on its monotone dual: :func:`project_box_halfspace`), until the field
  calls θₖ free. The first step is the nearest pose to θ₀ where the linearised field meets the
  threshold; on Panda-blocks one step is enough for most poses, deep ones take a few (the
  field's gradient deep inside an obstacle points less straight out).
- ``"adam"``: the paper's protocol: Adam (``lr``) on g, each pose frozen once g ≤ l_thres.

Then the exact labeller takes over (``shrink``, default): the field gave a direction, the
labeller finds the distance. Each move is cut to the first certified pose on its ray
θ₀ + t(θ_field − θ₀), t in [0, 4] (:func:`shrink_moves`: shortened where the field's margin
overshoots, extended where it falls short). With ``method="project"`` the poses still not certified get
the labeller's own nearest-free search (:func:`profrobot.nearest_free`, no field); with
``"adam"``, certify-and-continue lowers their threshold. What stays colliding is reported, never
returned as free.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import torch

from ..robot.robot import Robot
from .adam import BatchedAdam
from ..kinematics.limits import LIMIT_INSET, Limits
from ..field.identity import Field, field_robot
from ..field.layout import field_at_layout
from ..errors import InputError
from ..robot.gate import Layout, finite, positive, poses_within_limits, with_margin
from ..exact.certification import CLEARANCE, certified_summary, certify_poses, failures_of
from ..exact.labels import collides
from ..exact.oracle import nearest_free


@dataclass
class ResolveResult:
    """Outcome of :func:`resolve` for B poses.

    Attributes:
        poses: (B, K) float64 resolved poses, radians / metres, within the joint limits.
        iterations: (B,) int, field steps each pose took (projection or Adam steps; 0: it already met
            the threshold, or with ``method="project"`` was certified free as given).
        delta: (B,) float64, ‖θ_out − θ_in‖₂ in radians (continuous joints the short way round).
        certified: (B,) bool, the returned pose is certified free (:mod:`profrobot.exact.certification`).
        g: (B,) float32, the field at the field step's answer (before the exact labeller cuts the
            move: ``shrink``); at the input for poses returned as given.
        reached: (B,) bool, the field step's answer met its (final) field threshold (True for
            poses ``method="project"`` returned as given, certified).
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


Method = Literal["project", "adam"]
#: bisection steps of the projection's scalar multiplier (its bracket shrinks 2^-40)
_DUAL_STEPS = 40
#: the exact search for what the field's steps missed (``nearest_free``): rays and refinements
#: per pose. 32/64 keep the median Δθ within 1 % of 64/256's on Panda-blocks at a third of the
#: cost (benches/oracle.py)
_ORACLE_DIRECTIONS = 32
_ORACLE_REFINE = 64


def project_box_halfspace(theta0: torch.Tensor, a: torch.Tensor, b: torch.Tensor, lo: torch.Tensor,
                          hi: torch.Tensor) -> torch.Tensor:
    """The Euclidean projection of θ₀ (n, K) onto {x : a·x ≤ b} ∩ [lo, hi], row by row.

    a (n, K), b (n,), lo/hi (n, K) (±inf where a joint has no limit). Exactness: the minimiser of
    ½‖x − θ₀‖² + λ(a·x − b) over the box is x(λ) = clip(θ₀ − λa, lo, hi), and h(λ) = a·x(λ) is
    continuous and non-increasing in λ ≥ 0 (each term a_i·clip(θ₀_i − λa_i) falls with λ), so
    the multiplier is 0 when h(0) ≤ b and otherwise the root of h(λ) = b, bracketed (the
    unclipped root (h(0) − b)/‖a‖² is a lower bound, since clipping only slows h's fall; the upper
    end doubles until h ≤ b) and bisected. Where no λ reaches b (the half-space misses the box)
    the box point that minimises a·x along the path, x(λ_max), is returned: the best the
    linearisation allows.
    """
    def x_of(lam: torch.Tensor) -> torch.Tensor:
        return torch.clamp(theta0 - lam[:, None] * a, lo, hi)

    def h(lam: torch.Tensor) -> torch.Tensor:
        return (a * x_of(lam)).sum(1)

    zero = torch.zeros_like(b)
    over = h(zero) - b
    aa = (a * a).sum(1)
    # a row with no gradient has no direction to move in: it stays at clip(θ₀)
    need = (over > 0) & (aa > 1e-20)
    if not need.any():
        return x_of(zero)
    aa = aa.clamp_min(1e-20)
    top = torch.finfo(b.dtype).max / 4                 # λ stays finite (no inf·0 = NaN in x(λ))
    low = torch.where(need, torch.clamp(over / aa, max=top), zero)
    high = low.clone()
    for _ in range(_DUAL_STEPS):  # expand until h(high) ≤ b
        short = need & (h(high) > b) & (high < top)
        if not short.any():
            break
        high = torch.where(short, torch.clamp(2 * high + 1e-6, max=top), high)
    for _ in range(_DUAL_STEPS):
        mid = 0.5 * (low + high)
        above = h(mid) > b
        low = torch.where(need & above, mid, low)
        high = torch.where(need & ~above, mid, high)
    return x_of(torch.where(need, high, zero))


def _project(sdf, theta: torch.Tensor, rows: torch.Tensor, thresholds: torch.Tensor, lo: torch.Tensor,
             hi: torch.Tensor, budget: int, iterations: torch.Tensor, g_out: torch.Tensor) -> None:
    """Projection steps (module docs) of θ[rows] onto g ≤ threshold: each row stops at its first
    iterate where g meets its threshold, or after ``budget`` steps. Updates θ, the step counts
    and g (at the last iterate evaluated) in place."""
    active = rows
    for it in range(budget + 1):
        if len(active) == 0:
            break
        last = it == budget
        x = theta[active].detach().requires_grad_(not last)
        with torch.set_grad_enabled(not last):
            g = sdf(x)
        g_out[active] = g.detach()
        go = g.detach() > thresholds[active]
        if last or not go.any():
            break
        (grad,) = torch.autograd.grad(g.sum(), x)
        x, grad, active = x.detach()[go], grad[go], active[go]
        # the linearised constraint a·θ ≤ b: g(x) + ∇g(x)·(θ − x) ≤ c
        b = thresholds[active] - g.detach()[go] + (grad * x).sum(1)
        theta[active] = project_box_halfspace(x, grad, b, lo[active], hi[active])
        iterations[active] += 1


def shrink_moves(robot: Robot, q0: np.ndarray, q1: np.ndarray, limits: Limits, *, move: np.ndarray | None = None,
                 grid: int = 8, extend: float = 4.0, bisections: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Each move q0 → q1 ((B, K) radians / metres) cut to the first free pose on its ray
    q0 + t·d, then certified: shortened (t < 1) where q1 is free, extended (1 < t ≤ ``extend``)
    where it is not. ``move`` (B, K): d, the move as it was made (continuous joints unwrapped;
    default q1 − q0 with continuous joints the short way round); poses on the ray are wrapped and
    clipped to the joint limits, so a joint may end on a limit where the labeller certifies it.
    Returns (poses (B, K), certified (B,)); a row where nothing is certified keeps q1 (certified or
    not, as it is).

    Exactness: every pose returned as certified is one the labeller certified. The search scans
    t in steps of 1/``grid`` (first [0, 1], then beyond 1 for the rows where nothing was free)
    for the first free sample and bisects ``bisections`` times between it and the sample before,
    keeping a free upper end: the result lies within 2^-bisections / grid of the first free
    point after the last colliding sample scanned (the free set along a ray need not be an
    interval; the scan finds its first piece at the grid's resolution)."""
    out = q1.copy()
    ok = np.zeros(len(q1), dtype=bool)
    d = limits.diff(q1, q0) if move is None else np.asarray(move, dtype=np.float64)
    moved = np.abs(d).max(axis=1) > 0
    if (~moved).any():
        ok[~moved] = certify_poses(robot, q1[~moved])
    rows = np.flatnonzero(moved)
    if not len(rows):
        return out, ok

    def at(r: np.ndarray, t: np.ndarray) -> np.ndarray:  # the poses of rows r at t, one formula throughout
        return limits.numpy(q0[r] + t[:, None] * d[r])

    # the search asks the boolean fast path (MuJoCo's verdict, ~15x cheaper than the distances
    # certification needs); only the pose it settles on is certified, below
    def free(r: np.ndarray, t: np.ndarray) -> np.ndarray:
        return ~collides(robot, at(r, t))

    def scan(r: np.ndarray, ts: np.ndarray) -> np.ndarray:  # (len(r),) index of the first free t, or len(ts)
        hit = free(np.repeat(r, len(ts)), np.tile(ts, len(r))).reshape(len(r), len(ts))
        return np.where(hit.any(axis=1), hit.argmax(axis=1), len(ts))

    hi = np.full(len(rows), np.inf)
    lo = np.zeros(len(rows))
    inner = np.arange(grid + 1) / grid                          # t = 0 (q0) .. 1 (q1)
    first = scan(rows, inner)
    found = first <= grid
    hi[found] = inner[first[found]]
    lo[found] = inner[np.maximum(first[found] - 1, 0)]
    beyond = np.flatnonzero(~found)
    if len(beyond) and extend > 1:
        outer = 1 + np.arange(1, int(np.ceil((extend - 1) * grid)) + 1) / grid
        first = scan(rows[beyond], outer)
        hit = first < len(outer)
        hi[beyond[hit]] = outer[first[hit]]
        lo[beyond[hit]] = np.where(first[hit] > 0, outer[np.maximum(first[hit] - 1, 0)], 1.0)
    scanned = hi.copy()                                         # the first free sample of the scan
    search = np.isfinite(hi) & (hi > 0)
    for _ in range(bisections):
        r = np.flatnonzero(search)
        if not len(r):
            break
        mid = 0.5 * (lo[r] + hi[r])
        f = free(rows[r], mid)
        hi[r[f]] = mid[f]
        lo[r[~f]] = mid[~f]
    # certify where the search settled. A pose free but within CLEARANCE of contact tries, in
    # order: one and three steps further (the last bracket's width, at least 1e-5 rad), the
    # scan's free sample, and t = 1 (q1 itself); the first certified one stands
    width = np.maximum(hi - lo, 1e-5 / np.maximum(np.linalg.norm(d[rows], axis=1), 1e-300))
    todo = np.flatnonzero(np.isfinite(hi))
    for t in (hi, hi + width, hi + 3 * width, scanned, np.ones(len(rows))):
        if not len(todo):
            break
        good = certify_poses(robot, at(rows[todo], t[todo]))
        out[rows[todo[good]]] = at(rows[todo[good]], t[todo[good]])
        ok[rows[todo[good]]] = True
        todo = todo[~good]
    return out, ok


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


def exact_search(robot: Robot, q0: np.ndarray, bad: np.ndarray, limits: Limits, out: np.ndarray,
                 certified: np.ndarray, *, directions: int = 256, refine: int = 1024) -> None:
    """The exact labeller's own search for rows ``bad`` of ``q0`` (B, K), no field: the nearest
    free pose :func:`profrobot.nearest_free` finds (``directions`` rays, ``refine`` refinements),
    cut to the first certified pose on its ray (the search's own certified answer where that cut
    is not certified: the ray may graze contact before its end); a free answer the labeller does
    not certify sits on the boundary (bisected to its tolerance), so a little further along its
    ray is tried; one that ended free but uncertified for another reason (a gripper's fingers
    closed on their limit, touching: distance 0, not more than CLEARANCE) is searched again with
    other seeds. Writes the answers into ``out`` and ``certified`` (B,) in place."""
    if not len(bad):
        return
    near = nearest_free(robot, limits.numpy(q0[bad]), directions=directions, refine=refine)
    hit = np.isfinite(near.distance)
    if hit.any():
        assert near.certified is not None   # nearest_free certifies every pose it finds
        found = near.certified[hit]
        out[bad[hit][found]] = limits.numpy(near.poses[hit][found])
        certified[bad[hit][found]] = True
        # nearest_free leaves continuous joints unwrapped: its poses minus the inputs are its rays
        q1, ok = shrink_moves(robot, q0[bad[hit]], near.poses[hit], limits, move=near.poses[hit] - q0[bad[hit]])
        out[bad[hit][ok]] = q1[ok]
        certified[bad[hit][ok]] = True
        rows = np.flatnonzero(hit)
        for scale in (1.02, 1.05, 1.1, 1.2, 1.4):
            left = rows[~certified[bad[rows]]]
            if not len(left):
                break
            q2 = limits.numpy(q0[bad[left]] + scale * (near.poses[left] - q0[bad[left]]))
            good = certify_poses(robot, q2)
            out[bad[left][good]] = q2[good]
            certified[bad[left][good]] = True
    for seed in range(1, 9):
        left = bad[~certified[bad]]
        if not len(left):
            break
        again = nearest_free(robot, limits.numpy(q0[left]), seed=seed, directions=directions * (1 + seed // 4),
                             refine=refine)
        out[left[again.certified]] = limits.numpy(again.poses[again.certified])
        certified[left[again.certified]] = True


def _resolve_exact(poses, robot, layout, margin, start: float) -> ResolveResult:
    """:func:`resolve` with ``sdf=None``: the exact labeller's nearest-free search (its docs)."""
    if robot is None:
        raise InputError("resolve(sdf=None) searches with the exact labeller alone and needs robot= (the scene)")
    _, robot = field_at_layout(None, robot, layout)
    robot = with_margin(robot, margin)
    q0 = poses_within_limits(robot, poses)
    limits = Limits.of(robot)
    B = len(q0)
    out = q0.copy()
    certified = certify_poses(robot, q0) if B else np.zeros(0, dtype=bool)
    exact_search(robot, q0, np.flatnonzero(~certified), limits, out, certified)
    nan = np.full(B, np.nan, dtype=np.float32)
    return ResolveResult(poses=out, iterations=np.zeros(B, dtype=np.int64),
                         delta=np.linalg.norm(limits.diff(out, q0), axis=1), certified=certified, g=nan,
                         reached=certified.copy(), threshold=np.full(B, np.nan), seconds=time.perf_counter() - start,
                         history=[dict(round="exact search", threshold=float("nan"), certified=int(certified.sum()))])


def resolve(sdf: Field | None, poses: npt.ArrayLike, l_thres: float = -0.1, lr: float | None = None,
            iterations: int | None = None, *, method: Method = "project", shrink: bool = True,
            robot: Robot | None = None, refine: bool = True, refine_rounds: int = 4, refine_step: float = 0.1,
            refine_iterations: int | None = None, layout: Layout | None = None,
            margin: float = CLEARANCE) -> ResolveResult:
    """Resolve collisions of ``poses`` (B, K) (radians / metres, within joint limits) with the
    learned field ``sdf``, all poses in one batch (module docs).

    ``method="project"`` (default): each pose not certified free as given takes projection
    steps onto the linearised g ≤ ``l_thres`` inside the joint limits (module docs) until the
    field calls it free, ``iterations`` (default 5) steps at most. ``method="adam"``: the paper's protocol, Adam (``lr``,
    default 0.01) on g, each pose frozen as soon as g ≤ ``l_thres``, at most ``iterations``
    (default 1000) steps; continuous hinges wrapped, limited joints clamped after each step.
    Either way the field's steps keep a joint they move :data:`~profrobot.kinematics.limits.LIMIT_INSET`
    inside its limits (the labeller's search may end on a limit, where it certifies the pose).

    Every answer is certified by the exact labeller (``certified``). ``shrink`` (default): each
    move is cut to the first certified pose on its ray (module docs), so a pose certified as
    given comes back unchanged and a returned pose may lie as close as
    :data:`~profrobot.exact.certification.CLEARANCE` to contact (``shrink=False`` keeps the field's
    margin: the field's answer as it is). ``refine`` (default): poses still not certified get,
    with ``method="project"``, the exact labeller's nearest-free search from the input
    (:func:`profrobot.nearest_free`, 32 rays, 64 refinements, seeded by each pose's place among
    those searched: deterministic for the same batch); then, either method, rounds that
    lower their field threshold by ``refine_step`` each, up to ``refine_rounds`` rounds of
    ``refine_iterations`` steps (default ``iterations``). Poses left colliding are reported in
    ``result.failures``, never hidden. ``robot``: the labeller's robot (default: the bundled
    scene the field was trained on). ``scene``: for a field of a family of scenes
    (:mod:`profrobot.robot.family`), the layout δ to work at; answers are certified at exactly that
    layout. ``margin``: metres every certified answer keeps from the obstacles
    (:mod:`profrobot.robot.margin`; an estimated layout's :attr:`~profrobot.perception.layouts.LayoutEstimate.margin`
    makes answers certified at the estimate free at the true layout).

    ``sdf=None`` (``robot=`` required): no field, the exact labeller alone. Each pose not certified
    as given gets the nearest-free search (:func:`profrobot.nearest_free`, 256 rays, 1024
    refinements), its move cut to the first certified pose on its ray (or taken a little further
    where the search ended on the boundary), searched again with other seeds where it ended on a
    pose free but not certified; slower than the field's step, but it needs no training (a scene
    seen once, a layout just estimated).

    Cost (``"project"``): one to a few field gradients per colliding pose, ~25 labelled poses on
    its ray, and the nearest-free search for the few the field's direction misses (1 % on
    Panda-blocks, 5 % on the UR5e).
    """
    start = time.perf_counter()
    if sdf is None:
        return _resolve_exact(poses, robot, layout, margin, start)
    sdf, robot = field_at_layout(sdf, robot, layout)
    robot = with_margin(field_robot(sdf, robot), margin)
    q0 = poses_within_limits(robot, poses)
    l_thres = finite("l_thres", l_thres)
    if method not in ("project", "adam"):
        raise InputError(f"method must be 'project' or 'adam'; got {method!r}")
    if method == "project" and lr is not None:
        raise InputError("lr is the step size of method='adam'; method='project' has none (pass method='adam' "
                         "for the paper's Adam protocol)")
    lr = positive("lr", 0.01 if lr is None else lr)
    iterations = positive("iterations", (5 if method == "project" else 1000) if iterations is None else iterations,
                          integer=True, allow_zero=True)
    refine_rounds = positive("refine_rounds", refine_rounds, integer=True, allow_zero=True)
    refine_step = positive("refine_step", refine_step)
    refine_iterations = iterations if refine_iterations is None else positive("refine_iterations", refine_iterations, integer=True)

    like = sdf.joint_limits
    theta = torch.as_tensor(q0, dtype=like.dtype, device=like.device).clone()
    B, K = theta.shape
    limits = Limits.of(robot, theta)
    thresholds = torch.full((B,), l_thres, dtype=theta.dtype, device=theta.device)
    steps_taken = torch.zeros(B, dtype=torch.long, device=theta.device)
    g = torch.full((B,), float("nan"), dtype=theta.dtype, device=theta.device)
    theta_in = theta.clone()

    def result(sel=slice(None)) -> np.ndarray:
        # the input plus the float32 displacement: a pose that never moved comes back bit for bit
        moved = (theta[sel] - theta_in[sel]).cpu().numpy().astype(np.float64)
        return limits.numpy(q0[sel] + moved)

    if method == "adam":
        opt = BatchedAdam((B, K), lr, theta)

        def descend(rows_t: torch.Tensor, budget: int) -> None:
            _descend(sdf, theta, rows_t, thresholds, opt, limits, budget, steps_taken, g)

        todo = np.arange(B)
    else:
        # the box each joint may move in: LIMIT_INSET inside its limits, or where it already is if
        # it starts closer (a joint the projection does not need to move stays put); continuous
        # hinges unbounded (unwrapped here, wrapped on return)
        lo_j, hi_j = limits.bounds(LIMIT_INSET)
        inf = torch.full_like(lo_j, float("inf"))
        lo = torch.where(limits.continuous, -inf, torch.minimum(lo_j, theta_in))
        hi = torch.where(limits.continuous, inf, torch.maximum(hi_j, theta_in))

        def descend(rows_t: torch.Tensor, budget: int) -> None:
            _project(sdf, theta, rows_t, thresholds, lo, hi, budget, steps_taken, g)

        free_in = certify_poses(robot, q0)   # nothing to resolve: returned as given
        todo = np.flatnonzero(~free_in)
        if len(todo) < B:
            with torch.no_grad():
                done = torch.as_tensor(np.flatnonzero(free_in), device=theta.device)
                g[done] = sdf(theta[done])

    def answer(rows: np.ndarray) -> np.ndarray:
        """The field's answers for ``rows``, certified, shortened by the labeller (``shrink``)."""
        q1 = result(rows)
        if not shrink:
            ok = certify_poses(robot, q1)
        else:  # the move as the field made it: continuous joints unwrapped
            moved = (theta[rows] - theta_in[rows]).cpu().numpy().astype(np.float64)
            q1, ok = shrink_moves(robot, q0[rows], q1, limits, move=moved)
        out[rows] = q1
        return ok

    out = q0.copy()
    certified = np.ones(B, dtype=bool)
    if len(todo):
        descend(torch.as_tensor(todo, device=theta.device), iterations)
        certified[todo] = answer(todo)
    history: list[dict[str, Any]] = [dict(round=0, threshold=l_thres, certified=int(certified.sum()))]

    def again(bad: np.ndarray, threshold: float) -> np.ndarray:
        rows_t = torch.as_tensor(bad, device=theta.device)
        thresholds[rows_t] = threshold
        if method == "adam":
            opt.reset(rows_t)
        descend(rows_t, refine_iterations)
        answer(bad)
        return out[bad]

    if method == "project" and refine and not certified.all():
        # the exact labeller's own search (no field) for what the field's step missed: the
        # nearest free pose it finds from the input, then cut to a certified pose on that ray
        exact_search(robot, q0, np.flatnonzero(~certified), limits, out, certified, directions=_ORACLE_DIRECTIONS,
                     refine=_ORACLE_REFINE)
        history.append(dict(round="exact search", threshold=l_thres, certified=int(certified.sum())))
    rounds = certify_and_continue(robot, certified, again, l_thres=l_thres, step=refine_step,
                                  rounds=refine_rounds if refine else 0, history=history)

    g_np = g.cpu().numpy()
    thr = thresholds.cpu().numpy().astype(np.float64)
    reached = g_np <= thr
    if method == "project":
        reached[free_in] = True        # certified as given: no field step was needed
    return ResolveResult(poses=out, iterations=steps_taken.cpu().numpy(),
                         delta=np.linalg.norm(limits.diff(out, q0), axis=1), certified=certified,
                         g=g_np, reached=reached, threshold=thr,
                         seconds=time.perf_counter() - start, rounds=rounds, history=history)
