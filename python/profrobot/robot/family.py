"""Families of scenes: obstacles that move, described by *scene joints* δ beside the robot's θ.

A family is one MuJoCo model. Each movable obstacle is a body on slide / hinge joints with finite
ranges (the family's ranges), and the model names those joints in a custom text element,
``<custom><text name="profrobot:scene_joints" data="box_x box_y box_yaw"/></custom>``. So every
layout δ is an ordinary MuJoCo scene: the exact labeller labels the full vector (θ, δ) like any
pose, and :func:`profrobot.crosscheck` compares it with ``mj_collision`` unchanged.

Scene bodies (bodies moved by scene joints only) never collide with the world body or with each
other: the family adds those ``<exclude>``s to its spec, so MuJoCo, our reference, agrees. A layout
is the scene with every scene joint pinned at its value (:class:`PinnedLayout`): the bodies
keep their world pose and lose their joints, an ordinary static scene.

This module edits ``mujoco.MjSpec`` objects only; :class:`profrobot.Robot` uses it
(``with_obstacles`` with :class:`Moves`, ``with_scene_joints``, ``at``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TypeAlias

import mujoco
import numpy as np
import numpy.typing as npt

from ..errors import InputError

__all__ = ["Moves", "SCENE_JOINTS_TEXT", "Layout"]

#: a family's layout δ as the entry points take it (``layout=``): an array (D,) in
#: ``robot.scene_joints`` order (radians / metres), one per pose (B, D) where an entry point says
#: so, or ``{scene joint: value}``; exported as :data:`profrobot.robot.gate.Layout`
Layout: TypeAlias = npt.ArrayLike | Mapping[str, float]

#: the name of the MJCF custom text that lists a family's scene joints (space-separated)
SCENE_JOINTS_TEXT = "profrobot:scene_joints"

_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _range(owner: str, key: str, value, *, angle: bool) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{owner}: {key} must be a (low, high) pair of numbers; got {value!r}") from None
    unit = "radians" if angle else "metres"
    if not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
        raise InputError(f"{owner}: {key} must be a finite range (low < high) in {unit}; got ({lo}, {hi}). "
                         "Leave it out (None) to keep the obstacle fixed in that coordinate.")
    if angle and hi - lo > 2 * math.pi:
        raise InputError(f"{owner}: {key} spans {hi - lo:.3f} rad, more than a full turn (2π)")
    return lo, hi


@dataclass(frozen=True)
class Moves:
    """How an obstacle moves within a family of scenes (give it as ``Box(..., moves=Moves(...))``).

    ``x``, ``y``, ``z``: (low, high) offsets of the obstacle's centre along the *world* axes,
    metres, from its ``pos``; ``yaw``: (low, high) rotation about the world z axis through its
    centre, radians, applied on top of its ``quat``. None keeps that coordinate fixed. Each
    coordinate becomes one scene joint named ``{obstacle name}_{x|y|z|yaw}``, in that order.

    Example: ``Moves(x=(-0.15, 0.15), y=(-0.15, 0.15), yaw=(-math.pi / 4, math.pi / 4))``.
    """

    x: Sequence[float] | None = None
    y: Sequence[float] | None = None
    z: Sequence[float] | None = None
    yaw: Sequence[float] | None = None

    def coordinates(self, owner: str = "Moves") -> list[tuple[str, str, tuple, tuple[float, float]]]:
        """(suffix, "slide" | "hinge", world axis, (low, high)) of each moving coordinate."""
        out = []
        for key in ("x", "y", "z", "yaw"):
            r = _range(owner, f"moves.{key}", getattr(self, key), angle=key == "yaw")
            if r is not None:
                out.append((key, "hinge" if key == "yaw" else "slide", _AXES.get(key, (0.0, 0.0, 1.0)), r))
        if not out:
            raise InputError(f"{owner}: Moves() moves nothing; give at least one of x, y, z, yaw (or moves=None)")
        return out


# --------------------------------------------------------------------------------------------
# The scene-joint list in a spec / compiled model
# --------------------------------------------------------------------------------------------

def _text(spec: mujoco.MjSpec):
    return next((t for t in spec.texts if t.name == SCENE_JOINTS_TEXT), None)


def spec_scene_joints(spec: mujoco.MjSpec) -> list[str]:
    t = _text(spec)
    return t.data.split() if t is not None else []


def _set_spec_scene_joints(spec: mujoco.MjSpec, names: list[str]) -> None:
    t = _text(spec)
    if not names:
        if t is not None:
            spec.delete(t)
        return
    if t is None:
        spec.add_text(name=SCENE_JOINTS_TEXT, data=" ".join(names))
    else:
        t.data = " ".join(names)


def model_scene_joints(m: mujoco.MjModel) -> list[str]:
    """The scene joints a compiled model names (its ``profrobot:scene_joints`` text), in order."""
    for i in range(m.ntext):
        if mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_TEXT, i) == SCENE_JOINTS_TEXT:
            adr, size = int(m.text_adr[i]), int(m.text_size[i])
            return bytes(m.text_data[adr:adr + size]).split(b"\0")[0].decode().split()
    return []


def _bodies_with(spec: mujoco.MjSpec, joints: set[str]) -> list:
    return [b for b in spec.bodies if any(j.name in joints for j in b.joints)]


def _subtree(body) -> list:
    out = [body]
    for child in body.bodies:
        out += _subtree(child)
    return out


def _exclude_scene_bodies(spec: mujoco.MjSpec, new: list, old: list) -> None:
    """Scene bodies ``new`` and the bodies below them never collide with the world or with the
    other scene bodies' subtrees (``old`` and each other): MuJoCo ``<exclude>``s, so MuJoCo and
    the labeller agree, and a layout pinned into a static scene (where MuJoCo filters those pairs
    as welded together) labels like the family."""
    names = {(e.bodyname1, e.bodyname2) for e in spec.excludes}
    world = spec.worldbody.name or "world"
    done = [b.name for o in old for b in _subtree(o)]
    for top in new:
        group = [b.name for b in _subtree(top)]
        for name in group:
            for other in [world] + done:
                if (other, name) not in names and (name, other) not in names:
                    spec.add_exclude(bodyname1=other, bodyname2=name)
                    names.add((other, name))
        done += group


def add_moving_geom(spec: mujoco.MjSpec, owner: str, name: str | None, moves: Moves, pos: np.ndarray,
                    geom_args: dict) -> None:
    """A movable obstacle: a body at ``pos`` (world axes) on one joint per moving coordinate, its
    geom inside (``geom_args``: type, size, quat, rgba...), the joints listed as scene joints."""
    if not name:
        raise InputError(f"{owner}: a moving obstacle needs a name (its scene joints are named after it)")
    coords = moves.coordinates(owner)
    existing = spec_scene_joints(spec)
    old_bodies = _bodies_with(spec, set(existing))
    body = spec.worldbody.add_body(name=name, pos=pos)
    # joints move the body, not the dynamics: a fixed, harmless inertia so any geom compiles
    body.mass, body.inertia, body.explicitinertial = 1.0, [1e-3, 1e-3, 1e-3], True
    joints = []
    for key, kind, axis, (lo, hi) in coords:
        jname = f"{name}_{key}"
        body.add_joint(name=jname, type=mujoco.mjtJoint.mjJNT_HINGE if kind == "hinge" else mujoco.mjtJoint.mjJNT_SLIDE,
                       axis=axis, range=[lo, hi], limited=mujoco.mjtLimited.mjLIMITED_TRUE)
        joints.append(jname)
    body.add_geom(name=name, **geom_args)
    _set_spec_scene_joints(spec, existing + joints)
    _exclude_scene_bodies(spec, [body], old_bodies)


def mark_scene_joints(spec: mujoco.MjSpec, names: Sequence[str]) -> None:
    """Marks the joints ``names`` of ``spec`` as scene joints (after those already marked) and
    excludes the scene bodies' contacts with the world and each other."""
    existing = spec_scene_joints(spec)
    known = {j.name for j in spec.joints}
    missing = [n for n in names if n not in known]
    if missing:
        raise InputError(f"no joint named {', '.join(map(repr, missing))} in the model; joints: {', '.join(sorted(known))}")
    added = [n for n in names if n not in existing]
    old = _bodies_with(spec, set(existing))
    old_names = {b.name for b in old}
    new = [b for b in _bodies_with(spec, set(added)) if b.name not in old_names]
    _set_spec_scene_joints(spec, existing + added)
    _exclude_scene_bodies(spec, new, old)


@dataclass(frozen=True)
class PinnedLayout:
    """A spec edit: the scene joints ``values`` ((name, value) pairs) pinned, i.e. each scene body
    set at its world pose at those values (the other joints at ``qpos0``) and its joints removed.

    Exactness: a pinned body's new local frame is ``parent⁻¹ · body`` of MuJoCo's own forward
    kinematics at those values (float64), so its geoms sit where the family's do, to rounding
    (1e-16 m); the labels of the layout are the family's at (θ, δ) up to that rounding."""

    values: tuple

    def add_to(self, spec: mujoco.MjSpec) -> None:
        m = spec.compile()
        d = mujoco.MjData(m)
        d.qpos[:] = m.qpos0
        pinned = dict(self.values)
        for name, v in pinned.items():
            d.qpos[m.jnt_qposadr[m.joint(name).id]] = v
        mujoco.mj_kinematics(m, d)
        for body in _bodies_with(spec, set(pinned)):
            if body.frame is not None:
                raise InputError(f"scene body {body.name!r} sits in a <frame>; put it directly in its parent body")
            b = m.body(body.name).id
            p = int(m.body_parentid[b])
            neg = np.zeros(4)
            mujoco.mju_negQuat(neg, d.xquat[p])
            quat, pos = np.zeros(4), np.zeros(3)
            mujoco.mju_mulQuat(quat, neg, d.xquat[b])
            mujoco.mju_rotVecQuat(pos, d.xpos[b] - d.xpos[p], neg)
            body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT  # else euler/axisangle/... would override quat
            body.pos, body.quat = pos, quat
            for j in list(body.joints):
                spec.delete(j)
        _set_spec_scene_joints(spec, [n for n in spec_scene_joints(spec) if n not in pinned])


@dataclass(frozen=True)
class MarkedSceneJoints:
    """A spec edit: :func:`mark_scene_joints` of ``names``."""

    names: tuple

    def add_to(self, spec: mujoco.MjSpec) -> None:
        mark_scene_joints(spec, self.names)
