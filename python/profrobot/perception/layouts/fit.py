"""Fitting a family's scene joints to points: robust Gauss–Newton on exact signed distances.

Each *movable obstacle* is a scene body (a body with scene joints) with its drawn geoms
(:class:`Obstacle`); its joints ``δ_j`` (D_j values, within the family's ranges) place it by
MuJoCo's own kinematics. A point ``p`` is explained by obstacle ``j`` when its signed distance

    r_j(p; δ_j) = min over the obstacle's geoms s of  sdf_s(R_s(δ_j)ᵀ (p − x_s(δ_j)))

is near 0 (:mod:`.shapes`). Moving the obstacle with joint rate ``δ̇_k`` moves the body point at
``p`` with velocity ``v_k + ω_k × (p − x_body)`` (finite differences of MuJoCo's kinematics, exact
for slides, O(h) for hinges), so the field moves the other way:

    ∂r_j/∂δ_k = −∇r_j(p) · (v_k + ω_k × (p − x_body)).

The loss is Geman–McClure, ``ρ(r) = r² / (r² + s²)`` (a point far from the obstacle costs at
most 1: clutter, leftover robot pixels and other obstacles' points do not pull), minimised by
iteratively reweighted Gauss–Newton with Levenberg damping, its scale ``s`` lowered in stages
(graduated non-convexity) from a few centimetres to the sensor's noise. Starts: a grid over the
obstacle's ranges scored by the same loss at the coarsest scale; the best few are refined and the
lowest final loss kept. Then every point is given to the obstacle that explains it best (the
union of the solids: smallest signed distance) and each obstacle is refined on its own points.
Everything is deterministic (no random draws).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from ...errors import InputError
from ...robot.robot import Robot
from .shapes import solid_of

__all__ = ["Obstacle", "Placer", "movable_obstacles", "fit_obstacle", "refine", "gm_loss"]

_FD = 1e-6          # finite-difference step of the kinematics (rad / m)


@dataclass(frozen=True)
class Obstacle:
    """A movable obstacle of a family: the scene body ``body`` (id, name), the indices ``joints``
    (D_j,) of its scene joints in δ, their ``qpos_adr`` and ``ranges`` (D_j, 2), its ``solids``."""

    name: str
    body: int
    joints: np.ndarray
    qpos_adr: np.ndarray
    ranges: np.ndarray
    angular: np.ndarray          # (D_j,) bool: hinge (radians) or slide (metres)
    solids: tuple
    bodies: tuple = ()           # the scene body and every body below it

    def extreme_points(self) -> list[np.ndarray]:
        return [s.extreme_points() for s in self.solids]


def movable_obstacles(family: Robot, geomgroup: Sequence[int] | np.ndarray) -> list[Obstacle]:
    """The family's movable obstacles: each top scene body (moved by scene joints, none of its
    ancestors is) with the joints of its subtree and the geoms drawn in ``geomgroup``."""
    m = family.mj_model
    scene = list(family.scene_joints)
    jid = [m.joint(n).id for n in scene]
    jbody = {j: int(m.jnt_bodyid[j]) for j in jid}
    parent = np.asarray(m.body_parentid)

    def top(b: int) -> int:
        t = b
        while parent[b] != 0:
            b = int(parent[b])
            if any(jb == b for jb in jbody.values()):
                t = b
        return t

    groups: dict[int, list[int]] = {}
    for k, j in enumerate(jid):
        groups.setdefault(top(jbody[j]), []).append(k)
    out = []
    for b, ks in groups.items():
        sub = [b] + [c for c in range(m.nbody) if _below(parent, c, b)]
        geoms = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in sub and geomgroup[min(int(m.geom_group[g]), 5)]
                 and m.geom_rgba[g, 3] > 0]
        if not geoms:  # nothing drawn: fit its collision geoms (what else would the camera see)
            geoms = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in sub]
        ranges = np.array([m.jnt_range[jid[k]] for k in ks], dtype=np.float64)
        angular = np.array([int(m.jnt_type[jid[k]]) == int(mujoco.mjtJoint.mjJNT_HINGE) for k in ks])
        adr = np.array([int(m.jnt_qposadr[jid[k]]) for k in ks])
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}"
        out.append(Obstacle(name, b, np.array(ks), adr, ranges, angular, tuple(solid_of(m, g) for g in geoms),
                            tuple(sub)))
    return out


def _below(parent: np.ndarray, c: int, b: int) -> bool:
    while c != 0:
        c = int(parent[c])
        if c == b:
            return True
    return False


class Placer:
    """MuJoCo kinematics of one family model at a fixed robot pose: where an obstacle's geoms
    are for its joint values, and how its body points move with them."""

    def __init__(self, m: mujoco.MjModel, qpos: np.ndarray):
        self.m = m
        self.d = mujoco.MjData(m)
        self.d.qpos[:] = qpos

    def frames(self, ob: Obstacle,
               delta_j: np.ndarray) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, np.ndarray]:
        """Geom frames [(x (3,), R (3, 3))] of ``ob``'s solids and the body's origin (3,), at ``delta_j``."""
        d = self.d
        d.qpos[ob.qpos_adr] = delta_j
        mujoco.mj_kinematics(self.m, d)
        return ([(d.geom_xpos[s.geom].copy(), d.geom_xmat[s.geom].reshape(3, 3).copy()) for s in ob.solids],
                d.xpos[ob.body].copy(), d.xmat[ob.body].reshape(3, 3).copy())

    def rates(self, ob: Obstacle, delta_j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The body's origin ``x`` (3,) and, per joint k, its linear ``v`` (D_j, 3) and angular
        ``w`` (D_j, 3) velocity per unit rate (finite differences)."""
        _, x0, R0 = self.frames(ob, delta_j)
        v = np.empty((len(delta_j), 3))
        w = np.empty((len(delta_j), 3))
        for k in range(len(delta_j)):
            e = np.array(delta_j, dtype=np.float64)
            e[k] += _FD
            _, x1, R1 = self.frames(ob, e)
            v[k] = (x1 - x0) / _FD
            S = (R1 @ R0.T - np.eye(3)) / _FD
            w[k] = 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])
        self.frames(ob, delta_j)
        return x0, v, w


def distances(placer: Placer, ob: Obstacle, delta_j: np.ndarray, P: np.ndarray, grad: bool = False):
    """Signed distances (N,) of world points ``P`` (N, 3) to ``ob`` at ``delta_j``, and with
    ``grad`` their Jacobian (N, D_j) with respect to its joints (module docs)."""
    frames, _, _ = placer.frames(ob, delta_j)
    r = np.full(len(P), np.inf)
    g = np.zeros((len(P), 3)) if grad else None
    for s, (x, R) in zip(ob.solids, frames):
        q = (P - x) @ R                              # local: Rᵀ (p − x)
        if g is not None:                            # grad
            d, gl = s.sdf_grad(q)
            better = d < r
            r = np.where(better, d, r)
            g[better] = gl[better] @ R.T             # world: R ∇
        else:
            r = np.minimum(r, s.sdf(q))
    if not grad:
        return r
    x0, v, w = placer.rates(ob, delta_j)
    rel = P - x0
    J = np.empty((len(P), len(delta_j)))
    for k in range(len(delta_j)):
        vel = v[k] + np.cross(w[k], rel)
        J[:, k] = -(g * vel).sum(axis=1)
    return r, J


def gm_loss(r: np.ndarray, s: float) -> float:
    """Geman–McClure: Σ r² / (r² + s²), each point costing at most 1."""
    r2 = r * r
    return float((r2 / (r2 + s * s)).sum())


def refine(placer: Placer, ob: Obstacle, delta_j: np.ndarray, P: np.ndarray, scales: Sequence[float],
           iterations: int = 12) -> tuple[np.ndarray, float]:
    """Iteratively reweighted, damped Gauss–Newton on the Geman–McClure loss at each scale of
    ``scales`` in turn, within the obstacle's ranges. Returns (δ_j, final loss)."""
    lo, hi = ob.ranges[:, 0], ob.ranges[:, 1]
    delta = np.clip(np.asarray(delta_j, dtype=np.float64), lo, hi)
    cost = np.inf
    for s in scales:
        lam = 1e-3
        r, J = distances(placer, ob, delta, P, grad=True)
        cost = gm_loss(r, s)
        for _ in range(iterations):
            w = (s * s / (r * r + s * s)) ** 2                    # IRLS weights of ρ
            A = J.T @ (w[:, None] * J)
            b = J.T @ (w * r)
            improved = False
            for _try in range(6):
                step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12) + 1e-12 * np.eye(len(delta)), -b)
                new = np.clip(delta + step, lo, hi)
                rn = distances(placer, ob, new, P)
                cn = gm_loss(rn, s)
                if cn < cost:
                    moved = np.abs(new - delta).max()
                    delta, cost = new, cn
                    lam = max(lam / 4, 1e-7)
                    improved = True
                    break
                lam *= 8
            if not improved or moved < 1e-7:
                break
            r, J = distances(placer, ob, delta, P, grad=True)
    return delta, cost


def grid_starts(ob: Obstacle, slide_step: float = 0.06, hinge_step: float = 0.3) -> np.ndarray:
    """A grid over the obstacle's ranges (S, D_j): per joint ``ceil(span / step) + 1`` values (3
    to 9), cell centres inclusive of both ends."""
    axes = []
    for (lo, hi), ang in zip(ob.ranges, ob.angular):
        n = int(np.clip(np.ceil((hi - lo) / (hinge_step if ang else slide_step)) + 1, 3, 9))
        axes.append(np.linspace(lo, hi, n))
    return np.array(list(itertools.product(*axes)), dtype=np.float64)


def fit_obstacle(placer: Placer, ob: Obstacle, P: np.ndarray, scales: Sequence[float], keep: int = 16,
                 distinct: int = 8, finish: int = 3) -> tuple[np.ndarray, float]:
    """The best of the grid starts, each scored at the coarsest scale: the ``keep`` best, and
    ``distinct`` more that are no grid neighbours of a better one (other basins: the coarse score
    often ranks several cells around one wrong basin first), get 4 Gauss–Newton steps at that
    scale; the ``finish`` best of those are refined through ``scales``: (δ_j, loss at the finest
    scale)."""
    starts = grid_starts(ob)
    s0 = scales[0]
    scores = np.array([gm_loss(distances(placer, ob, d, P), s0) for d in starts])
    order = np.argsort(scores, kind="stable")
    spacing = np.array([np.diff(np.unique(starts[:, k]))[:1].max(initial=1.0) for k in range(starts.shape[1])])
    chosen: list[int] = [int(i) for i in order[:keep]]
    basins: list[int] = []
    for i in order:
        if all(np.abs((starts[i] - starts[c]) / spacing).max() > 1.01 for c in basins):
            basins.append(int(i))
            if int(i) not in chosen:
                chosen.append(int(i))
            if len(basins) == distinct:
                break
    short = [refine(placer, ob, starts[i], P, scales[:1], iterations=4) for i in chosen]
    best, best_cost = None, np.inf
    for i in np.argsort([c for _, c in short], kind="stable")[:finish]:
        d, c = refine(placer, ob, short[i][0], P, scales)
        if c < best_cost - 1e-12:
            best, best_cost = d, c
    if best is None:   # every start's loss was not finite: the points cannot place this obstacle
        raise InputError(f"the depth points given for obstacle {ob.name!r} place it nowhere (no start of the fit "
                         "reaches a finite loss)")
    return best, best_cost


def reach_box(placer: Placer, ob: Obstacle, pad: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo, hi) (3,) holding the obstacle at every corner of its ranges (and
    the middle), padded by ``pad`` metres: the points it could explain."""
    corners = list(itertools.product(*[(lo, 0.5 * (lo + hi), hi) for lo, hi in ob.ranges]))
    pts = []
    for c in corners:
        frames, _, _ = placer.frames(ob, np.array(c))
        for s, (x, R) in zip(ob.solids, frames):
            pts.append(s.extreme_points() @ R.T + x)
    allp = np.concatenate(pts)
    return allp.min(axis=0) - pad, allp.max(axis=0) + pad


def displacement_sigma(placer: Placer, ob: Obstacle, delta_j: np.ndarray, cov: np.ndarray) -> float:
    """Largest 1-σ displacement (metres) of any extreme point of the obstacle under joint
    covariance ``cov`` (D_j, D_j): max over points of sqrt(λ_max(J_p Σ J_pᵀ))."""
    frames, _, _ = placer.frames(ob, delta_j)
    x0, v, w = placer.rates(ob, delta_j)
    worst = 0.0
    for s, (x, R) in zip(ob.solids, frames):
        for p in s.extreme_points() @ R.T + x:
            Jp = (v + np.cross(w, p - x0)).T          # (3, D_j)
            worst = max(worst, float(np.sqrt(max(np.linalg.eigvalsh(Jp @ cov @ Jp.T).max(), 0.0))))
    return worst


def covariance(placer: Placer, ob: Obstacle, delta_j: np.ndarray, P: np.ndarray, s: float) -> tuple[np.ndarray, float]:
    """The joints' covariance (D_j, D_j) at the fit (Gauss–Newton: σ̂² (Jᵀ W J)⁻¹, W the robust
    weights, σ̂² the weighted residual variance) and σ̂ (metres)."""
    r, J = distances(placer, ob, delta_j, P, grad=True)
    w = (s * s / (r * r + s * s)) ** 2
    n_eff = float(w.sum())
    dof = max(n_eff - len(delta_j), 1.0)
    sigma2 = float((w * r * r).sum() / dof)
    A = J.T @ (w[:, None] * J)
    # a direction the points do not constrain keeps a huge variance (never pinv's zero)
    ridge = 1e-9 * max(float(np.trace(A)) / len(delta_j), 1e-12)
    cov = sigma2 * np.linalg.inv(A + ridge * np.eye(len(delta_j)))
    return cov, float(np.sqrt(sigma2))
