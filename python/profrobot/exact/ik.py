"""Goals in task space: certified collision-free inverse kinematics, and motion to a pose.

:func:`ik` puts a frame of the robot (a MuJoCo site, body or geom) at target poses: the Rust
core's Levenberg–Marquardt on the SE(3) error with the closed-form Jacobian, several seeds per
target (the start first), joint limits, couplings and continuous joints kept, every returned pose
certified by the exact labeller (``rust/ik/mod.rs`` has the method). :func:`plan_to_pose` plans a
certified path from a joint pose to a frame pose. Base layer: no torch.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np
import numpy.typing as npt

from .certification import CLEARANCE
from ..errors import InputError, InputTypeError
from .planning import PathResult, plan_path
from ..robot import world as _world
from ..robot.robot import Robot
from .labels import sample_poses
from ..robot.gate import (Layout, as_poses, count, joint_mask, positive, robot_at, seed as check_seed,
                          threads as check_threads, with_layout)

__all__ = ["IKResult", "ik", "frame_of", "plan_to_pose", "PoseMotion", "as_targets"]


_REASONS = {0: "certified", 1: "unreachable: no seed came within the tolerances (the best error is reported)",
            2: "reached only in collision: every pose that reaches it collides or comes within the clearance"}


@dataclass
class IKResult:
    """The answers for N targets.

    Attributes:
        poses: (N, K) radians / metres (a family's θ with ``layout=``): certified where
            ``certified``, else the best pose found (never certified as reaching the target).
        reached: (N,) bool, the frame is within the tolerances of the target.
        certified: (N,) bool, reached and certified free by the exact labeller.
        position_error: (N,) metres; rotation_error: (N,) radians (0 for position-only targets).
        iterations: (N,) Levenberg–Marquardt steps over every seed tried; seeds: (N,) seeds tried.
        outcome: (N,) 0 certified, 1 unreachable, 2 reached only in collision (:attr:`reasons`).
        seconds: wall time of the call.
        notes: target index → what more is known of it: for a target reached only in collision
            with joints that do not move the frame kept at their start values, whether another
            value of them reaches it certified (the pose ``ik(..., moving=[...])`` would give).
    """

    poses: np.ndarray
    reached: np.ndarray
    certified: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    iterations: np.ndarray
    seeds: np.ndarray
    outcome: np.ndarray
    seconds: float
    notes: dict[int, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def reasons(self) -> list[str]:
        """Why each answer is what it is, in words."""
        return [f"reached only in collision {self.notes[i]}" if i in self.notes else _REASONS[int(o)]
                for i, o in enumerate(self.outcome)]

    @property
    def failures(self) -> np.ndarray:
        """Indices of targets not certified."""
        return np.flatnonzero(~self.certified)

    def summary(self) -> str:
        n = len(self)
        ok = self.certified
        worst = (f"worst certified error {self.position_error[ok].max() * 1e3:.2g} mm, "
                 f"{self.rotation_error[ok].max() * 1e3:.2g} mrad; " if ok.any() else "")
        return (f"{n} targets: {ok.sum()} certified ({ok.mean():.1%}), {(self.outcome == 1).sum()} unreachable, "
                f"{(self.outcome == 2).sum()} reached only in collision; {worst}{1e3 * self.seconds / max(n, 1):.2f} ms "
                f"per target, {self.seeds.mean():.1f} seeds")


def frame_of(robot: Robot, frame: str) -> tuple[int, np.ndarray, np.ndarray]:
    """``(body id, position (3,), quaternion (w, x, y, z) (4,))`` of the frame named ``frame``
    in its body: a MuJoCo site, body or geom (looked up in that order)."""
    if not isinstance(frame, str):
        raise InputTypeError(f"frame must be the name of a site, body or geom; got {type(frame).__name__}")
    known = _world.frame(robot, frame)   # (a robot derived without compiling: no compile for its frames)
    if known is not None:
        if known[0] == 0:
            raise InputError("frame 'world' does not move: name a site, body or geom of the robot")
        return known
    m = robot.mj_model
    for kind, obj in (("site", mujoco.mjtObj.mjOBJ_SITE), ("body", mujoco.mjtObj.mjOBJ_BODY),
                      ("geom", mujoco.mjtObj.mjOBJ_GEOM)):
        i = mujoco.mj_name2id(m, obj, frame)
        if i < 0:
            continue
        if kind == "site":
            return int(m.site_bodyid[i]), np.array(m.site_pos[i]), np.array(m.site_quat[i])
        if kind == "body":
            if i == 0:
                raise InputError("frame 'world' does not move: name a site, body or geom of the robot")
            return i, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
        return int(m.geom_bodyid[i]), np.array(m.geom_pos[i]), np.array(m.geom_quat[i])

    def names(obj, n):
        return [mujoco.mj_id2name(m, obj, i) for i in range(n) if mujoco.mj_id2name(m, obj, i)]

    sites, bodies = names(mujoco.mjtObj.mjOBJ_SITE, m.nsite), names(mujoco.mjtObj.mjOBJ_BODY, m.nbody)
    raise InputError(f"frame {frame!r} is not a site, body or geom of {robot.name}; sites: {', '.join(sites) or 'none'}; "
                     f"bodies: {', '.join(bodies[1:])}")


def as_targets(targets: npt.ArrayLike, name: str = "targets") -> tuple[np.ndarray, np.ndarray | None]:
    """``(positions (N, 3), quaternions (N, 4) or None)`` from world transforms (N, 4, 4) / (4, 4)
    or positions (N, 3) / (3,), metres; a rotation that is not orthonormal (to 1e-6) with
    determinant +1, a last row other than (0, 0, 0, 1), or a non-finite entry is refused by name."""
    if hasattr(targets, "detach"):
        targets = targets.detach().cpu().numpy()
    try:
        t = np.asarray(targets, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputTypeError(f"{name} must be (N, 4, 4) transforms or (N, 3) positions (metres); got "
                             f"{type(targets).__name__} ({e})") from e
    if t.ndim in (1, 2) and t.shape[-1] == 3:
        t = t.reshape(-1, 3)
        quat = None
    elif t.ndim in (2, 3) and t.shape[-2:] == (4, 4):
        t = t.reshape(-1, 4, 4)
        quat = "rot"
    else:
        raise InputError(f"{name} must be (N, 4, 4) world transforms of the frame or (N, 3) positions; got shape "
                         f"{np.shape(targets)}")
    if len(t) == 0:
        raise InputError(f"{name} is empty")
    bad = ~np.isfinite(t)
    if bad.any():
        idx = tuple(int(v) for v in np.argwhere(bad)[0])
        raise InputError(f"{name}[{', '.join(map(str, idx))}] is {t[idx]}; targets must be finite")
    if quat is None:
        return np.ascontiguousarray(t), None
    R = t[:, :3, :3]
    off = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    wrong = np.flatnonzero((off > 1e-6) | (det <= 0))
    if len(wrong):
        i = int(wrong[0])
        raise InputError(f"{name}[{i}]'s rotation is not a rotation (RᵀR differs from I by {off[i]:.2g}, det "
                         f"{det[i]:.3g}): orthonormalise it")
    last = np.abs(t[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
    if (last > 1e-12).any():
        i = int(np.flatnonzero(last > 1e-12)[0])
        raise InputError(f"{name}[{i}]'s last row must be (0, 0, 0, 1); got {t[i, 3]}")
    q = np.empty((len(t), 4))
    for i in range(len(t)):
        mujoco.mju_mat2Quat(q[i], np.ascontiguousarray(R[i]).ravel())
    return np.ascontiguousarray(t[:, :3, 3]), q


def _starts(robot: Robot, start: npt.ArrayLike | None, n: int) -> np.ndarray:
    """(n, K) starts: ``start`` (K,) or (n, K), or the middle of the joint limits (on the
    couplings). A family reaching here has no layout: its starts are full poses over θ and δ,
    and the middle of its ranges is no layout it was given (refused by the gate's message)."""
    if start is None:
        if robot.is_family:
            robot_at(robot)   # refuses a family without a layout, with the gate's one message
        return np.repeat(robot.project(robot.joint_limits.mean(1))[None], n, axis=0)
    q = as_poses(robot, with_layout(robot, start, None, "start"), name="start")
    if len(q) == 1:
        q = np.repeat(q, n, axis=0)
    if len(q) != n:
        raise InputError(f"start must be one pose (K,) or one per target ({n}, K); got {len(q)} poses")
    return np.ascontiguousarray(q)


def ik(robot: Robot, targets: npt.ArrayLike, *, frame: str, start: npt.ArrayLike | None = None,
       layout: Layout | None = None, position_tolerance: float = 1e-4, rotation_tolerance: float = 1e-3,
       seeds: int = 128, iterations: int = 60, seed: int = 0, escape: bool = True, margin: float = CLEARANCE,
       locked: Sequence[str] = (), moving: Sequence[str] = (), posture: npt.ArrayLike | None = None,
       free_axis: str | npt.ArrayLike | None = None, tool: npt.ArrayLike | None = None,
       threads: int | None = None) -> IKResult:
    """Joint poses that put ``frame`` (a site, body or geom name) at ``targets``, certified free.

    ``targets``: (N, 4, 4) world transforms of the frame, or (N, 3) positions (position only),
    metres. ``start``: (K,) or (N, K) joint poses the answers should stay near (default: the
    middle of the joint limits); joints that do not move the frame keep their start values.
    ``layout``: a family's layout δ, where it is pinned (``start`` then θ, and so are the
    answers; without one a family's starts and answers are full poses). A target is
    *reached* within ``position_tolerance`` metres and ``rotation_tolerance`` radians (the
    solver iterates to a hundredth of them); a reached pose is certified by the exact labeller
    (no contact, every pair more than :data:`~profrobot.exact.certification.CLEARANCE` apart, within
    limits and on its couplings). Up to ``seeds`` seeds per target (the start, three
    perturbations of it, then uniform draws from ``seed``); among certified solutions the one
    nearest the start is returned. Unreachable targets come back not reached, with their best
    error and ``reasons``; nothing is certified that does not reach its target. A seed that
    reaches the target in contact first tries to move out (``escape``): the pairs nearer than
    5 mm enter as linearised distance rows beside the target's (``rust/ik/mod.rs``), and the pose it
    ends in is certified like any other. Same ``seed``, same answers, for any thread count.
    ``margin``: metres every answer keeps from the obstacles (:mod:`profrobot.robot.gate`).
    ``locked``: names of joints that keep their ``start`` values exactly (a gripper's jaw, a
    joint the task must not move); the rest solve for the target. ``moving``: names of joints
    that do not move the frame but may move to make the answer free (a gripper's jaw closed on
    an obstacle at its start value); without it such joints keep their start values, and a
    target reached only with another value of them says so in :attr:`IKResult.reasons`.
    ``posture``: (K,) a joint pose the answers should be near (radians / metres, within the
    limits): each seed that reaches its target then moves towards it in the target's null space
    (what the target leaves free: a 7-joint arm's elbow, the roll about a free axis, every
    orientation of a position-only target), staying on the target, and among certified answers
    the one nearest the posture is returned (without it, the one nearest the start). A target
    that fixes every joint leaves the answer where it was. ``free_axis``: an axis of the
    frame (``"x"``, ``"y"``, ``"z"`` or a (3,) vector in its own coordinates) whose rotation is
    free: the target fixes where it points, not the angle about it (a symmetric part grasped at
    any angle about the tool axis; the rotation error is then the angle between the two axes).
    ``tool``: a (4, 4) transform or (3,) offset (metres) of the tool in the frame's coordinates;
    the targets are then the tool's poses (the model is not edited).

    ``reached`` and ``outcome`` never disagree: a target is reached when a seed's errors are
    within the tolerances (whether it stopped there or at the hundredth the solver aims for), and
    only then is it certified or reported "reached only in collision"."""
    robot = robot_at(robot, layout=layout, margin=margin, family=True)
    held = joint_mask(robot, locked, "locked")
    asked = joint_mask(robot, moving, "moving")
    if held is not None and asked is not None and any(h and a for h, a in zip(held, asked)):
        both = [n for n, h, a in zip(robot.joint_names, held, asked) if h and a]
        raise InputError(f"joints both locked and moving: {', '.join(both)}")
    t0 = time.perf_counter()
    prefer = None
    if posture is not None:
        p = as_poses(robot, posture, name="posture", check_limits=True)
        if p.shape != (1, robot.njoint):
            raise InputError(f"posture must be one pose of {robot.njoint} joints; got shape {np.shape(posture)}")
        prefer = p[0].tolist()
    pos, quat = as_targets(targets)
    body, lpos, lquat = frame_of(robot, frame)
    lpos, lquat = with_tool(lpos, lquat, tool)
    axis = free_axis_of(free_axis)
    if axis is not None and quat is None:
        raise InputError("free_axis needs orientation targets ((N, 4, 4) transforms): position-only targets leave "
                         "every axis free already")
    position_tolerance = positive("position_tolerance", position_tolerance)
    rotation_tolerance = positive("rotation_tolerance", rotation_tolerance)
    seeds = count("seeds", seeds)
    iterations = count("iterations", iterations)
    starts = _starts(robot, start, len(pos))
    seed, threads = check_seed(seed), check_threads(threads)

    def solve(rows: np.ndarray | slice, moving_mask: list[bool] | None) -> dict:
        return robot.core.ik(pos[rows], quat[rows] if quat is not None else None, starts[rows], body, lpos.tolist(),
                             lquat.tolist(), seeds=seeds, iterations=iterations, tol_pos=position_tolerance / 100,
                             tol_rot=rotation_tolerance / 100, accept_pos=position_tolerance,
                             accept_rot=rotation_tolerance, clearance=CLEARANCE, seed=seed, escape=bool(escape),
                             held=held, moving=moving_mask, posture=prefer, free_axis=axis, threads=threads)

    out = solve(slice(None), asked)
    poses = out["poses"]
    pe, re = out["position_error"], out["rotation_error"]
    reached = (pe <= position_tolerance) & (re <= rotation_tolerance)
    certified = out["outcome"] == 0
    notes: dict[int, str] = {}
    # Reached only in collision with joints kept that do not move the frame (a jaw at its start
    # value): does another value of them reach it certified? Say so, with the value found.
    none = [False] * robot.njoint
    kept = (~frame_moved_by(robot, frame) & ~np.asarray(held or none) & ~np.asarray(asked or none)
            & ~np.isin(np.arange(robot.njoint), robot.scene_index))
    stuck = np.flatnonzero(out["outcome"] == 2)
    if len(stuck) and kept.any():
        names = [n for n, k in zip(robot.joint_names, kept) if k]
        again = solve(stuck, (kept | np.asarray(asked or none)).tolist())
        for i, ok, q in zip(stuck, again["outcome"] == 0, again["poses"]):
            values = ", ".join(f"{n}={q[robot.joint_names.index(n)]:.4g}" for n in names)
            notes[int(i)] = (f"with {', '.join(names)} at their start values: another value of them reaches it "
                             f"certified ({values}; pass moving={names!r})" if ok else
                             f"(every pose that reaches it collides or comes within the clearance, also with "
                             f"{', '.join(names)} free to move)")
    # one verdict: reached exactly where the outcome is not "unreachable" (rust/ik/mod.rs accepts a
    # seed at the tolerances, not only at the hundredth it iterates to; tests/test_ik_options.py)
    return IKResult(poses=poses, reached=reached, certified=certified, position_error=pe, rotation_error=re,
                    iterations=out["iterations"], seeds=out["seeds"], outcome=out["outcome"],
                    seconds=time.perf_counter() - t0, notes=notes)


_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def free_axis_of(free_axis: str | npt.ArrayLike | None) -> list[float] | None:
    """A free axis of the frame: ``"x"``, ``"y"``, ``"z"`` or a nonzero (3,) vector in the frame's
    own coordinates, as a unit list; None for none. Anything else is refused naming it."""
    if free_axis is None:
        return None
    if isinstance(free_axis, str):
        if free_axis not in _AXES:
            raise InputError(f"free_axis must be 'x', 'y', 'z' or a (3,) vector in the frame's coordinates; got {free_axis!r}")
        return list(_AXES[free_axis])
    try:
        a = np.asarray(free_axis, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputTypeError(f"free_axis must be 'x', 'y', 'z' or a (3,) vector; got {type(free_axis).__name__}") from None
    if a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) < 1e-9:
        raise InputError(f"free_axis must be a nonzero finite (3,) vector in the frame's coordinates; got {a.tolist()}")
    return (a / np.linalg.norm(a)).tolist()


def with_tool(lpos: np.ndarray, lquat: np.ndarray, tool: npt.ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
    """The frame ``(lpos, lquat)`` (in its body) moved by ``tool``: a (4, 4) transform or a (3,)
    offset (metres) in the frame's own coordinates (a tool centre point, a gripper's fingertip
    point), so that the targets are the tool's poses. None leaves the frame as it is."""
    if tool is None:
        return lpos, lquat
    t = np.asarray(tool, dtype=np.float64)
    if t.shape == (3,):
        offset, t = t, np.eye(4)
        t[:3, 3] = offset
    pos, quat = as_targets(t, "tool")
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, lquat)
    q = np.zeros(4)
    mujoco.mju_mulQuat(q, lquat, quat[0] if quat is not None else np.array([1.0, 0.0, 0.0, 0.0]))
    return lpos + rot.reshape(3, 3) @ pos[0], q

def frame_moved_by(robot: Robot, frame: str) -> np.ndarray:
    """(K,) bool: the joints that move ``frame`` (those on the bodies from the world to its body)."""
    body, _, _ = frame_of(robot, frame)
    parent, jnt_body = robot.body_parents, robot.joint_bodies
    chain = set()
    while body > 0:
        chain.add(int(body))
        body = int(parent[body])
    return np.array([int(b) in chain for b in jnt_body])


@dataclass
class PoseMotion:
    """A motion to a frame pose, or why there is none.

    - ``plan``: the planner's :class:`~profrobot.PathResult` for the goal tried last (certified
      continuously when ``certified``), None when no candidate reached the target or the time ran
      out before one was tried;
    - ``goal`` (K,): the joint pose the motion ends in (certified, reaching the target), or None;
    - ``ik``: the :class:`IKResult` of the last candidate computed, or None;
    - ``candidates``: IK candidates tried by the planner;
    - ``outcome``: ``"certified"``, ``"no path found"`` (candidates reached the target, the
      planner found no certified path to any in ``max_time``), ``"no candidate reached"`` (no IK
      candidate reaches the target certified free; ``ik.reasons`` says why) or ``"time ran out"``
      (``max_time`` was spent before the first candidate was planned to).
    """

    plan: PathResult | None
    goal: np.ndarray | None
    ik: IKResult | None
    candidates: int
    outcome: str

    @property
    def certified(self) -> bool:
        """Whether :attr:`path` is a certified motion from the start to the target."""
        return self.plan is not None and bool(self.plan.found and self.plan.certified)

    @property
    def path(self) -> np.ndarray | None:
        """(N, K) the waypoints, radians / metres (``plan.path``), or None without a plan."""
        return None if self.plan is None else self.plan.path


def plan_to_pose(robot: Robot, start: npt.ArrayLike, target: npt.ArrayLike, *, frame: str, layout: Layout | None = None,
                 margin: float = CLEARANCE, candidates: int = 8, max_time: float = 10.0, seed: int = 0,
                 locked: Sequence[str] = (), moving: Sequence[str] = (), posture: npt.ArrayLike | None = None,
                 free_axis: str | npt.ArrayLike | None = None, tool: npt.ArrayLike | None = None,
                 threads: int | None = None, **plan_options) -> PoseMotion:
    """A certified path from the joint pose ``start`` (K,) to a pose of ``frame`` (``target``:
    (4, 4) world transform or (3,) position, metres).

    IK candidates, each certified: the solution nearest ``start`` first, then solutions from
    seeded uniform starts (other branches: an elbow flipped, a wrist turned), up to
    ``candidates``, each computed only when the ones before could not be reached. Each is tried
    with :func:`profrobot.plan_path` (``plan_options``: its options), ``max_time`` seconds
    shared among them; the first path found is returned with the goal pose it chose. Always a
    :class:`PoseMotion`: when no candidate reaches the target certified free, or the time runs
    out, its ``outcome`` says so (bad input raises :class:`InputError`). ``margin``: metres the
    path keeps from the obstacles; a family plans at ``layout`` (:mod:`profrobot.robot.gate`).
    ``locked``, ``moving``: as for :func:`ik` (joints that do not move the frame stay at their
    ``start`` values, a gripper's jaw, unless named in ``moving``); ``posture``: as for
    :func:`ik`, the goal poses it prefers (the nearest candidate is then near the posture)."""
    robot = robot_at(robot, layout=layout, margin=margin)
    q0 = as_poses(robot, start, name="start", check_limits=True)
    if len(q0) != 1:
        raise InputError(f"start must be one pose (K,); got {len(q0)}")
    pos, quat = as_targets(target, "target")
    if len(pos) != 1:
        raise InputError(f"target must be one pose ((4, 4) or (3,)); got {len(pos)}")
    candidates = count("candidates", candidates)
    max_time = positive("max_time", max_time)
    tgt = pos if quat is None else np.asarray(target, dtype=np.float64).reshape(1, 4, 4)
    joint_mask(robot, locked, "locked")   # refused here, before any candidate is computed
    asked = joint_mask(robot, moving, "moving")
    others = sample_poses(robot, max(candidates - 1, 1), seed=check_seed(seed))
    # another branch of the arm, not another jaw: what does not move the frame stays at the start
    still = ~frame_moved_by(robot, frame) & ~np.asarray(asked or [False] * robot.njoint)
    others[:, still] = q0[0, still]
    goals: list[tuple[np.ndarray, IKResult]] = []
    made = 0
    last_ik = None

    def candidate(c: int):
        """Candidate ``c`` (computed on first need), or None when fewer distinct ones exist."""
        nonlocal made, last_ik
        while len(goals) <= c and made < candidates:
            near = q0[0] if made == 0 else others[made - 1]
            sol = ik(robot, tgt, frame=frame, start=near, seed=int(seed) + made, locked=locked, moving=moving,
                     posture=posture, free_axis=free_axis, tool=tool, threads=threads)
            made += 1
            last_ik = sol
            if sol.certified[0] and not any(np.abs(sol.poses[0] - g).max() < 1e-6 for g, _ in goals):
                goals.append((sol.poses[0], sol))
        return goals[c] if c < len(goals) else None

    # rounds of growing time budgets over the candidates, nearest first: a goal on a branch the
    # start cannot reach costs a short time-out, not the whole budget
    t0 = time.perf_counter()
    last = None
    for share in (0.005, 0.05, 1.0):
        for c in range(candidates):
            got = candidate(c)
            if got is None:
                break
            goal, sol = got
            left = max_time - (time.perf_counter() - t0)
            if left <= 0:
                return last if last is not None else PoseMotion(None, None, last_ik, c, "time ran out")
            budget = left / max(len(goals) - c, 1) if share == 1.0 else min(share * max_time, left)
            res = plan_path(robot, q0[0], goal, seed=int(seed) + c, max_time=budget, locked=locked, threads=threads,
                            **plan_options)
            found = bool(res.found and res.certified)
            last = PoseMotion(plan=res, goal=goal, ik=sol, candidates=c + 1,
                              outcome="certified" if found else "no path found")
            if found:
                return last
    if last is None:
        return PoseMotion(plan=None, goal=None, ik=last_ik, candidates=0, outcome="no candidate reached")
    return last
