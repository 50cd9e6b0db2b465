"""Input validation and the thin wrappers over the Rust labeller.

Validation happens here, once: the core re-checks shapes and finiteness but Python users get
the exception that names their problem.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .._core import interpolate as interpolate_so2
from ..robot.angles import wrap
from ..robot.equalities import EQUALITY_MODES, EqualityMode, settle
from ..robot.robot import Robot
from ..errors import InputError
from ..robot.gate import (CLEARANCE, Layout, as_poses, count, memory, robot_at, seed as check_seed,
                          threads as check_threads, with_layout, with_margin)


@dataclass
class Labels:
    """Exact collision labels of B poses.

    Attributes:
        collides: (B,) bool, any contact (self or scene).
        self_collides: (B,) bool, robot against robot.
        scene_collides: (B,) bool, robot against the static scene.
        n_pairs: (B,) int32, number of geom pairs in contact.
        min_distance: (B,) float64 metres, minimum signed distance over candidate pairs
            (negative: penetration depth), when asked for.
        colliding_pairs: (M, 2) int64 rows ``(pose index, pair index)``, when asked for; pair
            indices refer to ``robot.pair_geoms``.
    """

    collides: np.ndarray
    self_collides: np.ndarray
    scene_collides: np.ndarray
    n_pairs: np.ndarray
    min_distance: np.ndarray | None = None
    colliding_pairs: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.collides)

    def summary(self) -> str:
        n = len(self)
        return (f"{n} poses: {self.collides.mean():.1%} collide "
                f"({self.self_collides.mean():.1%} self, {self.scene_collides.mean():.1%} scene), "
                f"{self.n_pairs[self.collides].mean() if self.collides.any() else 0:.2f} pairs per colliding pose")


def label_poses(robot: Robot, poses: npt.ArrayLike, *, layout: Layout | None = None, margin: float = CLEARANCE,
                pairs: bool = False, distance: bool = False, check_limits: bool = True,
                threads: int | None = None) -> Labels:
    """Exact collision labels of ``poses`` (B, K) (radians / metres, MuJoCo joint order).

    Runs the Rust labeller in parallel (all cores unless ``threads``) with the GIL released;
    labels agree with MuJoCo's ``mj_collision`` (meshes as convex hulls, MuJoCo's pair filters).
    ``pairs`` adds the colliding pairs, ``distance`` the minimum signed distance per pose.
    A family's robot poses θ take their layout as ``layout=δ``. A limited joint outside its
    limits (a pose in degrees, say) is an :class:`InputError` naming the entry, unless
    ``check_limits=False``. ``margin``: a pose closer than this many metres to an obstacle is
    labelled in contact (:mod:`profrobot.robot.gate`).
    """
    robot = with_margin(robot, margin)
    q = as_poses(robot, with_layout(robot, poses, layout), check_limits=check_limits)
    out = robot.core.label(q, pairs=pairs, distance=distance, threads=check_threads(threads))
    return Labels(**out)


def collides(robot: Robot, poses: npt.ArrayLike, *, layout: Layout | None = None, margin: float = CLEARANCE,
             check_limits: bool = True, threads: int | None = None) -> np.ndarray:
    """Whether each of ``poses`` (B, K) (radians / metres, MuJoCo joint order) collides: (B,) bool.

    Exactly ``label_poses(robot, poses).collides``, faster: the Rust fast path stops at the first
    pair in contact, trying the pairs likeliest to be in contact first. Same validation,
    ``layout=``, ``margin=``, threads and GIL release as :func:`label_poses`; the same answer for
    any thread count.
    """
    robot = with_margin(robot, margin)
    q = as_poses(robot, with_layout(robot, poses, layout), check_limits=check_limits)
    return robot.core.collides(q, threads=check_threads(threads))


def sample_poses(robot: Robot, n: int, seed: int = 0, *, layout: Layout | None = None, margin: float = CLEARANCE,
                 threads: int | None = None, equalities: EqualityMode = "auto") -> np.ndarray:
    """``n`` poses (n, K) drawn uniformly within the joint limits (continuous hinges: [-pi, pi]).

    ``equalities`` (see :mod:`profrobot.robot.equalities`): ``"auto"`` computes every joint that a
    MuJoCo joint equality makes dependent from its independent joint (exact; a pose whose
    dependent joint lands outside its limits is redrawn: every pose is one the robot can take,
    :meth:`Robot.feasible`); ``"settle"``
    also projects each pose onto every active equality (connect/weld loops, tendons) with
    MuJoCo's constraint rows, replacing poses that do not settle within limits by further
    seeded draws; ``"ignore"`` samples every joint independently.

    The same ``seed`` gives the same poses whatever the thread count. A family samples its θ and
    δ, or its θ at ``layout``; the samples do not depend on ``margin`` (validated as everywhere).
    """
    robot = robot_at(robot, layout=layout, margin=margin, family=True)
    n = count("n", n)
    memory("n", n, robot.njoint)
    seed = check_seed(seed)
    if equalities not in EQUALITY_MODES:
        raise InputError(f"equalities must be one of {EQUALITY_MODES}; got {equalities!r}")
    threads = check_threads(threads)
    poses = robot.core.sample(int(n), int(seed), threads=threads)
    if equalities == "ignore":
        return poses
    robot.couplings.apply(poses)
    poses = _coupled_within_limits(robot, poses, int(seed), threads)
    if equalities == "auto" or all(e.enforced_by_default for e in robot.equalities if e.active):
        return poses
    return _settled(robot, poses, int(n), int(seed), threads)


def _coupled_within_limits(robot: Robot, poses: np.ndarray, seed: int, threads: int | None) -> np.ndarray:
    """``poses`` (on their couplings) with every row whose coupling puts a dependent joint outside
    its limits replaced, in order, by further draws from seeds derived from ``seed``: uniform
    over the poses the mechanism can take. Deterministic for any thread count."""
    if not robot.couplings:
        return poses
    bad = np.flatnonzero(~robot.feasible(poses))
    r = 0
    while len(bad):
        r += 1
        if r > 64:
            raise InputError(f"{robot.name}: its joint couplings put a dependent joint outside its limits in nearly "
                             f"every pose ({len(bad)} of {len(poses)} still after {r - 1} redraws); check the "
                             f"equalities' polycoef against the joints' ranges")
        extra = robot.core.sample(max(4 * len(bad), 64),
                                  int(np.random.SeedSequence([seed, 0xC0, r]).generate_state(1, np.uint64)[0]),
                                  threads=threads)
        robot.couplings.apply(extra)
        extra = extra[robot.feasible(extra)][: len(bad)]
        poses[bad[: len(extra)]] = extra
        bad = bad[len(extra):]
    return poses


def _settled(robot: Robot, poses: np.ndarray, n: int, seed: int, threads: int | None) -> np.ndarray:
    """``poses`` projected onto the equality manifold; failures (no convergence, or a limited
    joint pushed past its range) are replaced by draws from seeds derived from ``seed``."""
    lim, limited = robot.joint_limits, ~robot.continuous
    dof = np.asarray(robot.mj_model.jnt_dofadr, dtype=np.int64)
    kept, have, r = [], 0, 0
    while have < n:
        if r > 0:
            poses = robot.core.sample(n, int(np.random.SeedSequence([seed, r]).generate_state(1, np.uint64)[0]),
                                      threads=threads)
            robot.couplings.apply(poses)
        q, ok = settle(robot.mj_model, poses, robot.qpos_adr, dof)
        ok &= ~(((q < lim[:, 0] - 1e-9) | (q > lim[:, 1] + 1e-9)) & limited).any(axis=1)
        kept.append(q[ok][: n - have])
        have += len(kept[-1])
        r += 1
        if r > 50 and have == 0:
            raise InputError(f"{robot.name}: no pose settled onto its equality constraints within the joint "
                               f"limits after {r * n} draws")
    return np.concatenate(kept)


def interpolate(robot: Robot, start: npt.ArrayLike, goal: npt.ArrayLike, steps: int, *, layout: Layout | None = None,
                margin: float = CLEARANCE) -> np.ndarray:
    """Poses along SO(2)^K from ``start`` to ``goal``: (steps, K) for single poses, or
    (B, steps, K) for (B, K) batches. Continuous joints take the shortest arc; limited joints go
    straight (ends must be within limits); the dependent joints of joint equalities follow their
    independent ones (the motion the robot makes, and the one :func:`certify_motions` proves).
    Both end points are included. A family interpolates its θ at ``layout`` (or full poses); the
    path does not depend on ``margin`` (validated as everywhere)."""
    robot = robot_at(robot, layout=layout, margin=margin, family=True)
    single = np.ndim(start) == 1
    s = as_poses(robot, start, name="start", check_limits=True)
    g = as_poses(robot, goal, name="goal", check_limits=True)
    if s.shape != g.shape:
        raise InputError(f"start and goal must have the same shape; got {s.shape} and {g.shape}")
    steps = count("steps", steps, 2, why="both end points included")
    memory("steps", len(s), steps, robot.njoint)
    path = interpolate_so2(s, g, int(steps), np.ascontiguousarray(robot.continuous))
    if robot.couplings:   # the robot moves its independent joints; the dependent ones follow
        robot.couplings.apply(path.reshape(-1, robot.njoint))
    return path[0] if single else path


def so2_steps(robot: Robot, path) -> np.ndarray:
    """(M−1, K) joint moves between consecutive waypoints of ``path`` (M, K) (radians / metres):
    continuous hinges along the short arc (:func:`profrobot.robot.angles.wrap`), as :func:`interpolate`
    moves them."""
    d = np.diff(np.asarray(path, dtype=np.float64), axis=0)
    d[:, robot.continuous] = wrap(d[:, robot.continuous])
    return d
