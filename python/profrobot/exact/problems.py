"""Test problems for the field and the optimisers, drawn uniformly and labelled by the exact
labeller, seeded: colliding poses, free poses, and hard start/goal pairs (both ends free, the
straight SO(2) interpolation between them colliding). Used by the command line, the benches and
the tests, so that all of them pose the same kind of problem.
"""

from __future__ import annotations

import numpy as np

from .dataset import make_dataset
from ..robot import gate
from .labels import check_threads, interpolate, label_poses
from ..robot.gate import CLEARANCE, Layout
from ..robot.robot import Robot
from .certification import certify_poses
from ..errors import InputError
from ..robot.angles import wrap

__all__ = ["colliding_poses", "free_poses", "hard_pairs"]


def _poses(robot: Robot, n, collides: bool, seed: int, max_samples: int | None, threads: int | None, layout,
           margin: float) -> np.ndarray:
    robot = gate.robot_at(robot, layout=layout, margin=margin, family=True)
    n = gate.count("n", n)
    # rounds sized for a rare class (Panda-blocks: ~12 % of uniform poses collide)
    batch = min(100_000, max(1024, 16 * n))
    ds = make_dataset(robot, n, collided_fraction=1.0 if collides else 0.0, seed=seed, batch=batch,
                      max_samples=max_samples, progress=False, threads=threads)
    return ds.poses


def colliding_poses(robot: Robot, n: int, seed: int = 0, *, layout: Layout | None = None, margin: float = CLEARANCE,
                    max_samples: int | None = None, threads: int | None = None) -> np.ndarray:
    """(n, K) float64 uniform poses that the exact labeller finds colliding, seeded. Raises
    ValueError if fewer than ``n`` turn up within ``max_samples`` draws (default ``200 * n``)."""
    return _poses(robot, n, True, seed, max_samples, threads, layout, margin)


def free_poses(robot: Robot, n: int, seed: int = 0, *, layout: Layout | None = None, margin: float = CLEARANCE,
               max_samples: int | None = None, threads: int | None = None) -> np.ndarray:
    """(n, K) float64 uniform poses that the exact labeller finds free, seeded. Raises
    ValueError if fewer than ``n`` turn up within ``max_samples`` draws (default ``200 * n``)."""
    return _poses(robot, n, False, seed, max_samples, threads, layout, margin)


def _free_walks(robot: Robot, starts: np.ndarray, rng: np.random.Generator, walk: int, step: float,
                resolution: float = 0.01) -> np.ndarray:
    """From each start (m, K), ``walk`` random moves of L2 length ``step``, each taken only when
    its whole SO(2) segment is free at ``resolution`` (no joint moves more than that between
    checked poses): the end is reachable by construction."""

    q = starts.copy()
    m, k = q.shape
    lim, cont = robot.joint_limits, robot.continuous
    d_count = int(np.ceil(step / resolution)) + 1
    for _ in range(walk):
        d = rng.normal(size=(m, k))
        d *= step / np.linalg.norm(d, axis=1, keepdims=True)
        cand = q + d
        cand[:, cont] = wrap(cand[:, cont])
        cand[:, ~cont] = np.clip(cand[:, ~cont], lim[~cont, 0], lim[~cont, 1])
        robot.couplings.apply(cand)       # the dependent joints follow (the mechanism's own move)
        idx = np.flatnonzero(robot.feasible(cand))   # a dependent joint pushed past its limits: no move
        if len(idx) == 0:
            continue
        seg = interpolate(robot, q[idx], cand[idx], d_count).reshape(-1, k)      # (m' D, K)
        ok = robot.feasible(seg)
        ok[ok] = ~label_poses(robot, seg[ok]).collides
        take = idx[ok.reshape(len(idx), -1).all(axis=1)]
        q[take] = cand[take]
    return q


def hard_pairs(robot: Robot, n: int, seed: int = 0, *, layout: Layout | None = None, margin: float = CLEARANCE,
               steps: int = 100, density: int = 10, max_pairs: int | None = None, reachable: bool = True,
               walk: int = 150, walk_step: float = 0.3, threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``n`` start/goal pairs ``(starts, goals)``, each (n, K) float64: both certified free, on
    their joint couplings, and a sample of the straight SO(2) interpolation between them (``steps``
    waypoints, ``density`` times finer samples between them) not certified: a straight path
    refuted outright, so the continuous certificate that :func:`profrobot.plan_path` and
    :func:`profrobot.optim.plan_trajectory` certify with refuses it too. Seeded; raises
    ValueError if fewer than ``n`` turn up among ``max_pairs`` candidate pairs (default
    ``200 * n``).

    ``reachable=True`` (default): each goal is the end of a free random walk from its start
    (``walk`` moves of ``walk_step`` radians, every segment checked), so a path exists. Uniform
    pairs (``reachable=False``) can lie in different components of free space, with no path at
    all: a ±2π shoulder joint, say, on the other side of the floor, which a limited joint cannot
    wrap around; no planner can solve those. ``layout``, ``margin``: as everywhere
    (:mod:`profrobot.robot.gate`); a family needs its layout (a pair whose walk moved the
    obstacles would be no planning problem)."""
    robot = gate.robot_at(robot, layout=layout, margin=margin)
    n = gate.count("n", n)
    steps = gate.count("steps", steps)
    density = gate.count("density", density)
    if steps < 2:
        raise InputError(f"steps must be at least 2; got {steps}")
    threads = check_threads(threads)
    max_pairs = max_pairs or 200 * n

    starts, goals = [], []
    tried = found = 0
    r = 0
    while found < n:
        if tried >= max_pairs:
            raise InputError(f"only {found} of {n} start/goal pairs with a colliding straight path among "
                             f"{tried} free pairs; raise max_pairs")
        m = drawn = min(max_pairs - tried, max(16, 2 * (n - found)))
        round_seed = int(np.random.SeedSequence([seed, r]).generate_state(1, np.uint64)[0] >> 1)
        free = free_poses(robot, 2 * m, seed=round_seed, threads=threads)
        a, b = free[0::2], free[1::2]
        if reachable:
            b = _free_walks(robot, a, np.random.default_rng(round_seed), walk, walk_step)
            # a walk clipped at a joint limit can end exactly touching (fingers closed on each
            # other): free to the labels, a contact to MuJoCo and to the certification's
            # clearance rule; such goals are dropped
            ok = certify_poses(robot, b)
            a, b, m = a[ok], b[ok], int(ok.sum())
            if m == 0:
                tried += drawn
                r += 1
                continue
        dense = interpolate(robot, a, b, (steps - 1) * density + 1)        # (m, D, K)
        # not certified somewhere along the straight path (certify_poses screens with the cheap
        # boolean labels first and pays for distances only where they find it free)
        straight_collides = ~certify_poses(robot, dense.reshape(-1, robot.njoint), threads=threads).reshape(m, -1).all(axis=1)
        take = np.flatnonzero(straight_collides)[: n - found]
        starts.append(a[take])
        goals.append(b[take])
        found += len(take)
        tried += drawn
        r += 1
    return np.concatenate(starts), np.concatenate(goals)
