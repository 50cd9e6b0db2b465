"""A :class:`~profrobot.Robot` as a family of scenes, and derived scenes (``Robot``'s methods call
these with the robot): the scene joints that move obstacles, layouts δ checked against the
family's ranges, a family pinned at a layout (``Robot.at``), and a safety margin around the
obstacles (``Robot.with_margin``). What a family is: :mod:`profrobot.robot.family`; what a margin
guarantees: :mod:`profrobot.robot.margin`. Base layer: no torch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from ..errors import InputError, InputTypeError
from .family import MarkedSceneJoints, PinnedLayout, model_scene_joints
from .margin import CLEARANCE, ObstacleMargin, check_margin
from .pointcloud import CLOUD_GEOM_ID



def read_scene_joints(self, m: mujoco.MjModel) -> tuple[str, ...]:
    names = model_scene_joints(m)
    index = {n: j for j, n in enumerate(self.joint_names)}
    for n in names:
        j = index.get(n)
        if j is None:
            raise InputError(f"{self.name}: the model's profrobot:scene_joints names {n!r}, which is not a joint")
        if not m.jnt_limited[j]:
            raise InputError(f"{self.name}: scene joint {n!r} has no range; a family needs each scene joint's "
                             "range (limited=\"true\" range=\"low high\")")
    if len(set(names)) != len(names):
        raise InputError(f"{self.name}: profrobot:scene_joints lists a joint twice: {names}")
    if names:
        _check_scene_bodies(self, m, {index[n] for n in names})
    return tuple(sorted(names, key=index.__getitem__))  # MuJoCo joint order


def _check_scene_bodies(self, m: mujoco.MjModel, scene: set[int]) -> None:
    """What makes a layout pinned into a static scene label like the family: each scene body
    carries scene joints only, hangs from a body fixed to the world, has no robot joint below
    it, and its subtree is excluded (``<exclude>``) from the world and from the other scene
    bodies' subtrees (pinned, MuJoCo filters those pairs as welded together)."""
    bn = self.body_names
    tops = sorted({int(m.jnt_bodyid[j]) for j in scene})
    below = {t: [b for b in range(m.nbody) if int(m.body_weldid[b]) == t] for t in tops}
    for t in tops:
        sub = [self.joint_names[j] for j in range(m.njnt) if j not in scene and _is_below(m, int(m.jnt_bodyid[j]), t)]
        if sub:
            names = sub
            raise InputError(f"{self.name}: scene body {bn[t]!r} also moves with robot joints {names}; a scene "
                             "body carries scene joints only and has no robot joint below it")
        if int(m.body_weldid[m.body_parentid[t]]) != 0:
            raise InputError(f"{self.name}: scene body {bn[t]!r} hangs from {bn[int(m.body_parentid[t])]!r}, which "
                             "moves; a scene body's parent must be fixed to the world")
    excluded = {int(s) for s in m.exclude_signature}
    sig = lambda a, b: ((min(a, b) << 16) + max(a, b)) in excluded or ((max(a, b) << 16) + min(a, b)) in excluded
    missing, done = [], [0]
    for t in tops:
        for b in below[t]:
            missing += [(bn[o], bn[b]) for o in done if not sig(o, b)]
        done += below[t]
    if missing:
        lines = "".join(f'\n  <exclude body1="{a}" body2="{b}"/>' for a, b in missing[:8])
        raise InputError(f"{self.name}: scene bodies must not collide with the world or with each other (pinned at a "
                         f"layout, MuJoCo would filter those pairs); the model lacks {len(missing)} <exclude>(s):{lines}"
                         f"{' ...' if len(missing) > 8 else ''}\nAdd them to the MJCF's <contact>, or build the family "
                         "with robot.with_scene_joints(names), which adds them")


def _is_below(m: mujoco.MjModel, b: int, top: int) -> bool:
    while b > 0:
        if b == top:
            return True
        b = int(m.body_parentid[b])
    return False


def with_scene_joints(self, names: Sequence[str], *, name: str | None = None) -> Any:
    """:meth:`Robot.with_scene_joints` (see there)."""
    if isinstance(names, str) or not all(isinstance(n, str) for n in names):
        raise InputTypeError("names must be a list of joint names")
    edit = MarkedSceneJoints(tuple(names))
    spec = self._editable("with_scene_joints")
    edit.add_to(spec)
    return self._derived(spec, (edit,), name or self.name)


def is_family(self) -> bool:
    """:meth:`Robot.is_family` (see there)."""
    return bool(self.scene_joints)


def scene_index(self) -> np.ndarray:
    """:meth:`Robot.scene_index` (see there)."""
    return np.array([self.joint_names.index(n) for n in self.scene_joints], dtype=np.int64)


def robot_index(self) -> np.ndarray:
    """:meth:`Robot.robot_index` (see there)."""
    return np.setdiff1d(np.arange(self.njoint), self.scene_index)


def check_layout(self, layout, *, name: str = "layout") -> np.ndarray:
    """:meth:`Robot.check_layout` (see there)."""
    if not self.scene_joints:
        raise InputError(f"{self.name} is not a family of scenes (it has no scene joints), so it takes no {name}")
    D = len(self.scene_joints)
    if isinstance(layout, Mapping):
        unknown = sorted(set(layout) - set(self.scene_joints))
        missing = [n for n in self.scene_joints if n not in layout]
        if unknown or missing:
            raise InputError(f"{name} must give every scene joint of {self.name}: "
                             + "; ".join(filter(None, [f"unknown {unknown}" if unknown else "",
                                                       f"missing {missing}" if missing else ""])))
        layout = [layout[n] for n in self.scene_joints]
    if hasattr(layout, "detach"):  # a torch tensor
        layout = layout.detach().cpu().numpy()
    try:
        delta = np.array(layout, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name} must be {D} numbers (one per scene joint); got {layout!r}") from e
    if delta.shape != (D,):
        raise InputError(f"{name} must have shape ({D},), one value per scene joint {list(self.scene_joints)}; "
                         f"got shape {delta.shape}")
    limits = self.joint_limits[self.scene_index]
    for i, (v, (lo, hi), n) in enumerate(zip(delta, limits, self.scene_joints)):
        if not np.isfinite(v):
            raise InputError(f"{name}[{i}] ({n}) is {v}")
        if not lo - 1e-9 <= v <= hi + 1e-9:
            raise InputError(f"{name}[{i}] ({n}) = {v:.6g} is outside the family's range [{lo:.6g}, {hi:.6g}]: "
                             "refused rather than extrapolated; build a family with wider ranges")
    return np.clip(delta, limits[:, 0], limits[:, 1])


def compose(self, theta, layout) -> np.ndarray:
    """:meth:`Robot.compose` (see there)."""
    theta = np.asarray(theta, dtype=np.float64)
    one = theta.ndim == 1
    theta = np.atleast_2d(theta)
    ri = self.robot_index
    if theta.ndim != 2 or theta.shape[1] != len(ri):
        raise InputError(f"theta must have {len(ri)} columns (the robot joints of {self.name}); got shape {theta.shape}")
    out = np.empty((len(theta), self.njoint))
    out[:, ri] = theta
    out[:, self.scene_index] = self.check_layouts(layout, len(theta))
    return out[0] if one else out


def check_layouts(self, layout, n: int) -> np.ndarray:
    """:meth:`Robot.check_scenes` (see there)."""
    if hasattr(layout, "detach"):  # a torch tensor
        layout = layout.detach().cpu().numpy()
    if isinstance(layout, Mapping) or np.ndim(layout) != 2:
        return self.check_layout(layout)[None]
    rows = np.asarray(layout, dtype=np.float64)
    if len(rows) != n:
        raise InputError(f"layout must be (D,) or one layout per pose ({n}, D); got shape {rows.shape}")
    return np.stack([self.check_layout(d, name=f"layout[{i}]") for i, d in enumerate(rows)])


def at(self, layout, *, name: str | None = None) -> Any:
    """:meth:`Robot.at` (see there)."""
    delta = self.check_layout(layout)
    delta.setflags(write=False)
    key = (delta.tobytes(), name)

    def build() -> Any:
        _check_base_clear(self, delta)
        edit = PinnedLayout(tuple(zip(self.scene_joints, (float(v) for v in delta))))
        spec = self._editable("at(scene)")
        edit.add_to(spec)
        robot = self._derived(spec, (edit,), name or self.name)
        robot.layout, robot.family_fingerprint = delta, self.geometry_fingerprint
        return robot

    return _cached(self, "_layouts", key, build)


def _cached(self, cache: str, key, build) -> Any:
    """``build()``'s robot, kept in ``self.<cache>`` under ``key`` (the 4 latest): derived
    scenes cost a MuJoCo compile; pickles and deep copies leave the caches out."""
    memo = self.__dict__.setdefault(cache, {})
    if key not in memo:
        robot = build()
        if len(memo) >= 4:
            memo.pop(next(iter(memo)))
        memo[key] = robot
    return memo[key]


def with_margin(self, margin: float) -> Any:
    """:meth:`Robot.with_margin` (see there)."""
    m = check_margin(margin)
    if m <= max(CLEARANCE, self.margin):
        return self

    def build() -> Any:
        edit = ObstacleMargin(m)
        spec = self._editable("with_margin")
        edit.add_to(spec)
        robot = self._derived(spec, (edit,), self.name)
        robot.margin = m
        if self.cloud is not None:  # its balls get the margin too
            robot = robot.with_points(self.cloud)
        robot.geometry_fingerprint = self.geometry_fingerprint
        robot.layout, robot.family_fingerprint = self.layout, self.family_fingerprint
        return robot

    return _cached(self, "_margins", m, build)


def _check_base_clear(self, delta: np.ndarray) -> None:
    """Refuse a layout whose scene bodies touch, or come within :data:`CLEARANCE` of, a body
    fixed to the world (the robot's base, a static body). Those pairs do not depend on θ:
    on the family every pose would fail certification, while pinned, MuJoCo filters them
    (welded together), so the layout could not certify like the family (issue 33: an
    obstacle 0.5 µm from the base was accepted, then certified on one and not the other)."""
    m = self.mj_model
    d = mujoco.MjData(m)
    d.qpos[self.qpos_adr] = self.joint_limits.mean(1)
    d.qpos[self.qpos_adr[self.scene_index]] = delta
    mujoco.mj_kinematics(m, d)
    weld, gbody = self._arrays["body_weld"], dict(zip(self._arrays["geom_id"], self._arrays["geom_body"]))
    gbody[CLOUD_GEOM_ID] = 0  # the point cloud: on the world
    scene_welds = {int(self._arrays["jnt_body"][j]) for j in self.scene_index}
    for k, (g1, g2) in enumerate(self.pair_geoms):
        b1, b2 = int(gbody[int(g1)]), int(gbody[int(g2)])
        for a, b in ((b1, b2), (b2, b1)):
            if int(weld[a]) in scene_welds and int(weld[b]) == 0 and CLOUD_GEOM_ID not in (g1, g2):
                need = max(float(self.pair_margin[k]), CLEARANCE)
                dist = mujoco.mj_geomDistance(m, d, int(g1), int(g2), 10 * need + 1e-3, None)
                if dist <= need:
                    what = "overlaps" if dist <= 0 else f"is {dist:.3g} m from"
                    raise InputError(f"at this layout the obstacle body {self.body_names[a]!r} {what} "
                                     f"{self.body_names[b]!r}, which is fixed to the world (the robot's base or a "
                                     f"static body): every pose would collide or, within the certification's "
                                     f"clearance ({need:g} m), fail certification; choose another layout")
