"""A safety margin around the obstacles: what a result certified at an *estimated* scene keeps
at the true one.

:meth:`profrobot.Robot.with_margin` gives every obstacle geom a MuJoCo contact margin of at least
``margin`` metres (:class:`ObstacleMargin`, a spec edit). MuJoCo, and the labeller with it, count a
pair as in contact when its signed distance is below its margin, so on that robot:

- a pose is *certified* only if every robot–obstacle pair is at least ``margin`` apart (and every
  pair more than :data:`CLEARANCE`), and a motion only if that holds at every
  state of it (the continuous certificate of :mod:`profrobot.exact.certification`);
- self pairs (robot–robot) keep their own margins: the margin is about where the obstacles are,
  and the robot's own geometry is known.

**What it guarantees.** Let ``O`` be an obstacle as estimated and ``O'`` the same solid as it
really is. If no point of ``O`` moved by more than ``e`` metres (``O' ⊂ O ⊕ B(e)``, e.g. a rigid
error of translation ``t`` and rotation ``φ`` about a centre within ``r`` of every point of the
solid: ``e ≤ |t| + 2 r sin(|φ|/2)``), then for any robot geom ``G``

    dist(G, O') ≥ dist(G, O) − e ≥ margin − e > 0     whenever e < margin,

so a pose or motion certified with ``margin`` is free at the true layout. **What it assumes:** the
error bound ``e < margin`` holds for every obstacle (an estimate's :attr:`margin
<profrobot.perception.layouts.LayoutEstimate.margin>` is a bound with high probability under its noise
model, not a certainty), the obstacles are the shapes the model says, and what the model does not
contain (clutter nobody modelled) is not covered at all.

"Obstacle" here: every geom not on the robot, i.e. on a body that no robot joint moves and that
carries no robot joint below it: the world body's geoms (floor, table), static bodies, and the
bodies of a family's scene joints (pinned or not). The robot's fixed base is robot.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import mujoco
import numpy as np

from ..errors import InputError
from .family import spec_scene_joints

#: metres: the least distance every candidate pair keeps in a certified pose (what it means:
#: :mod:`profrobot.exact.certification`, which re-exports it, as :mod:`profrobot.robot` does).
CLEARANCE = 1e-6
"""Metres: the least distance every candidate pair keeps in a certified pose."""

__all__ = ["ObstacleMargin", "check_margin", "obstacle_bodies", "MAX_MARGIN", "CLEARANCE"]

#: metres: the largest safety margin accepted (a margin this large means the estimate is not one)
MAX_MARGIN = 0.25


def check_margin(margin: float, who: str = "margin") -> float:
    """``margin`` as a float in [0, :data:`MAX_MARGIN`] metres, else :class:`InputError` naming it."""
    try:
        m = float(margin)
    except (TypeError, ValueError):
        raise InputError(f"{who} must be a distance in metres; got {margin!r}") from None
    if not math.isfinite(m) or m < 0:
        raise InputError(f"{who} must be a finite distance ≥ 0 in metres; got {margin!r}")
    if m > MAX_MARGIN:
        raise InputError(f"{who} = {m:g} m is more than {MAX_MARGIN} m: an estimate that uncertain locates nothing; "
                         "estimate the layout again (closer cameras, more views) or pass the obstacles themselves")
    return m


def obstacle_bodies(m: mujoco.MjModel, scene_joints: Iterable[str]) -> np.ndarray:
    """(nbody,) bool: the model's obstacle bodies. A body is the robot's when a robot joint (any
    joint not in ``scene_joints``) moves it (on itself or an ancestor) or sits below it (its
    fixed base); every other body, the world body included, holds obstacles."""
    scene = set(scene_joints)
    robot_joint = np.zeros(m.nbody, bool)
    for j in range(m.njnt):
        if (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or "") not in scene:
            robot_joint[m.jnt_bodyid[j]] = True
    parent = np.asarray(m.body_parentid)
    moved = robot_joint.copy()
    for b in range(1, m.nbody):  # parents come before children in MuJoCo's body order
        moved[b] |= moved[parent[b]]
    base = np.zeros(m.nbody, bool)
    for b in range(m.nbody - 1, 0, -1):
        if robot_joint[b] or base[b]:
            p = parent[b]
            if p != 0:
                base[p] = True
    return ~(moved | base)


@dataclass(frozen=True)
class ObstacleMargin:
    """A spec edit: every obstacle geom's margin (and every explicit ``<pair>`` with one) raised to
    at least ``margin`` metres (module docs). Refused for a model that overrides contact margins
    globally (``<flag override="enable">``), where MuJoCo would ignore it."""

    margin: float

    def add_to(self, spec: mujoco.MjSpec) -> None:
        m = spec.compile()
        if m.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE:
            raise InputError("this model overrides every contact margin (<option><flag override=\"enable\"/>): "
                             "a safety margin on its obstacles would be ignored by MuJoCo; turn the override off")
        obstacle = obstacle_bodies(m, spec_scene_joints(spec))
        bodies = spec.bodies
        if len(bodies) != m.nbody:  # spec.bodies lists the world body and every body in compiled order
            raise InputError("could not match the spec's bodies to the compiled model's")
        names = set()
        for b, body in enumerate(bodies):
            if not obstacle[b]:
                continue
            for g in body.geoms:
                g.margin = max(float(g.margin), self.margin)
                if g.name:
                    names.add(g.name)
        for p in spec.pairs:
            if p.geomname1 in names or p.geomname2 in names:
                p.margin = max(float(p.margin), self.margin)
