"""Grasped objects: an obstacle that moves with a body of the robot, as spec edits (so MuJoCo
and the labeller agree on it).

``robot.attach(obstacle, to=body, at=pose)`` takes a fixed geom of the world (by name) off the
world and onto a new body welded to ``to``, where the robot holds it at ``pose`` (the grasp): its
place relative to ``to`` is what forward kinematics gives there, so it does not move at the
grasp. A new :class:`~profrobot.robot.obstacles.Obstacle` (named) can be attached instead, its
``pos`` / ``quat`` then in ``to``'s frame. ``robot.detach(name, at=pose)`` puts it back in the
world where ``to`` holds it at ``pose`` (the place).

What it touches. The held object is welded to ``to`` (which the compiler may fuse into ``to``): by MuJoCo's rules it never collides with
``to`` nor with a body whose parent is ``to`` (the fingers of a hand it is attached to), and is
checked against everything else (the world, the other links). ``touching=[bodies]`` lets it
touch more bodies (a ``<contact><exclude>`` of the object's body and each, the mechanism of the
robot's own excluded pairs); :meth:`Robot.detach` removes those.

Each edit is replayed from the robot's source when a robot is unpickled (``robot/sources.py``),
from the relative pose stored here: no forward kinematics on the way.

A primitive of the world (box, sphere, capsule, cylinder, ellipsoid) is attached without
compiling MuJoCo: the body and geom the compiler would make are written into the core's arrays
(:func:`profrobot.robot.world.with_held`, bit for bit the compiled model's, tested), about 2 ms
on a Panda in a MotionBenchMaker scene instead of a compile (70-140 ms); ``robot.mj_model``
compiles on first use and is checked against the fingerprint. ``detach`` of such an object is
written the same way (:func:`profrobot.robot.world.with_put`). Meshes and new obstacles compile.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import mujoco
import numpy as np
import numpy.typing as npt

from ..errors import InputError, InputTypeError
from . import world as _world
from .obstacles import Obstacle, apply_edit
from .poses import pose_array

__all__ = ["Attach", "Detach"]   # (attach, detach: the bodies of Robot.attach and Robot.detach)

#: geom attributes carried over when a geom changes body (its pose and size are set anew)
_CARRIED = ("type", "rgba", "contype", "conaffinity", "condim", "margin", "gap", "priority", "friction", "group",
            "meshname", "material", "solmix", "solref", "solimp")


def _compose(p1, q1, p2, q2) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``(p1, q1) ∘ (p2, q2)``."""
    p, q = np.zeros(3), np.zeros(4)
    mujoco.mju_rotVecQuat(p, np.asarray(p2, float), np.asarray(q1, float))
    mujoco.mju_mulQuat(q, np.asarray(q1, float), np.asarray(q2, float))
    return np.asarray(p1, float) + p, q / np.linalg.norm(q)


def _inverse(p, q) -> tuple[np.ndarray, np.ndarray]:
    qi, pi = np.zeros(4), np.zeros(3)
    mujoco.mju_negQuat(qi, np.asarray(q, float))
    mujoco.mju_rotVecQuat(pi, -np.asarray(p, float), qi)
    return pi, qi


def _mesh_frame(m: mujoco.MjModel, g: int) -> tuple[np.ndarray, np.ndarray]:
    """The pose the compiler moved a mesh geom's frame by (its mesh re-centred); identity else."""
    if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and m.geom_dataid[g] >= 0:
        k = m.geom_dataid[g]
        return np.array(m.mesh_pos[k]), np.array(m.mesh_quat[k])
    return np.zeros(3), np.array([1.0, 0, 0, 0])


def _place_geom(spec: mujoco.MjSpec, body, name: str, attrs: dict, size, pos, quat) -> None:
    g = body.add_geom(name=name)
    for k, v in attrs.items():
        setattr(g, k, v)
    g.size = np.asarray(size, float)
    g.fromto = np.full(6, np.nan)
    g.pos, g.quat = np.asarray(pos, float), np.asarray(quat, float)


@dataclass(frozen=True)
class Attach:
    """A spec edit: the world geom ``name`` (or the new ``obstacle``) onto a body ``name``
    welded to ``to`` at ``pos`` / ``quat`` (``to``'s frame), allowed to touch ``touching``."""

    name: str
    to: str
    pos: tuple[float, ...]
    quat: tuple[float, ...]
    size: tuple[float, ...] = ()
    geom_pos: tuple[float, ...] = (0.0, 0.0, 0.0)
    geom_quat: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0)
    touching: tuple[str, ...] = ()
    obstacle: Obstacle | None = None

    def add_to(self, spec: mujoco.MjSpec) -> None:
        parent = spec.body(self.to)
        body = parent.add_body(name=self.name, pos=np.asarray(self.pos, float), quat=np.asarray(self.quat, float))
        if self.obstacle is not None:
            ob = self.obstacle
            body.add_geom(name=ob.name, rgba=np.asarray(ob.rgba, float), **ob._geom_args(spec))
        else:
            old = spec.geom(self.name)
            attrs = {k: getattr(old, k) for k in _CARRIED}
            spec.delete(old)
            _place_geom(spec, body, self.name, attrs, self.size, self.geom_pos, self.geom_quat)
        for t in self.touching:
            spec.add_exclude(bodyname1=self.name, bodyname2=t)


@dataclass(frozen=True)
class Detach:
    """A spec edit: the held object ``name`` back to the world at ``pos`` / ``quat`` (its geom's
    frame in the world), its body and excludes removed."""

    name: str
    pos: tuple[float, ...]
    quat: tuple[float, ...]
    size: tuple[float, ...]

    def add_to(self, spec: mujoco.MjSpec) -> None:
        body = spec.body(self.name)
        (old,) = body.geoms
        attrs = {k: getattr(old, k) for k in _CARRIED}
        for e in list(spec.excludes):
            if self.name in (e.bodyname1, e.bodyname2):
                spec.delete(e)
        spec.delete(body)
        _place_geom(spec, spec.worldbody, self.name, attrs, self.size, self.pos, self.quat)


def _edited(robot, spec: mujoco.MjSpec, edit: "Attach | Detach"):
    """The robot of ``spec`` after ``edit`` (carried in its source: pickles replay it)."""
    apply_edit(spec, edit, f"{type(edit).__name__.lower()} {edit.name!r}")
    return robot._derived(spec, (edit,), robot.name)


def _names(m: mujoco.MjModel, kind: mujoco.mjtObj, n: int) -> list[str]:
    return [mujoco.mj_id2name(m, kind, i) or "" for i in range(n)]


def _one_pose(robot, at: npt.ArrayLike, name: str) -> np.ndarray:
    """``at`` as one pose (1, K) within the limits, refused by ``name`` otherwise."""
    q = pose_array(robot, at, name=name, check_limits=True)
    if q.shape != (1, robot.njoint):
        raise InputError(f"{name} must be one pose of {robot.njoint} joints; got shape {np.shape(at)}")
    return np.ascontiguousarray(q)


def _kinematics(robot, at: npt.ArrayLike, name: str) -> mujoco.MjData:
    q = _one_pose(robot, at, name)
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_adr] = q[0]
    mujoco.mj_kinematics(m, d)
    return d


def _body(robot, name: object, what: str) -> int:
    """The body ``name``'s id (from the robot's body names: no compile)."""
    if not isinstance(name, str):
        raise InputTypeError(f"{what} must be a body's name (str); got {type(name).__name__}")
    if name not in robot.body_names:
        raise InputError(f"{what}={name!r} is not a body of {robot.name}; its bodies: "
                         f"{', '.join(n for n in robot.body_names if n)}")
    return robot.body_names.index(name)


def attach(robot, obstacle: str | Obstacle, *, to: str, at: npt.ArrayLike | None = None,
           touching: Sequence[str] = ()):
    """``robot`` holding ``obstacle`` with body ``to`` (module docs; :meth:`Robot.attach`)."""
    b = _body(robot, to, "to")
    if robot._arrays["body_weld"][b] == 0:
        raise InputError(f"to={to!r} does not move with the robot's joints; attach to a link of the robot")
    if isinstance(touching, str) or not all(isinstance(t, str) for t in touching):
        raise InputTypeError(f"touching must be a list of body names; got {touching!r}")
    for t in touching:
        _body(robot, t, "touching")
    touching = tuple(dict.fromkeys(touching))   # (each body once)
    if isinstance(obstacle, str):
        g = _world.held_geom(robot, obstacle)
        if g is not None:   # a primitive of the world: written into the arrays (robot/world.py), no compile
            return _held(robot, obstacle, g, b, at, touching)
    m = robot.mj_model
    if isinstance(obstacle, Obstacle):
        if at is not None:
            raise InputError("at is for a geom of the world; a new obstacle's pos and quat are in to's frame")
        if not obstacle.name:
            raise InputError(f"{obstacle.label}: an attached obstacle needs a name (to detach it by)")
        if obstacle.moves is not None:
            raise InputError(f"{obstacle.label}: an attached obstacle moves with {to!r}, not on scene joints")
        if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, obstacle.name) >= 0 or \
                mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, obstacle.name) >= 0:
            raise InputError(f"{obstacle.label}: the name {obstacle.name!r} is taken in {robot.name}")
        pos, quat = np.asarray(obstacle.pos, float), np.asarray(obstacle.quat, float)
        if pos.shape != (3,) or quat.shape != (4,) or not np.isfinite(pos).all() or not np.isfinite(quat).all() \
                or not np.linalg.norm(quat) > 0:
            raise InputError(f"{obstacle.label}: pos must be 3 finite numbers and quat 4, not zero")
        edit = Attach(obstacle.name, to, tuple(pos), tuple(quat / np.linalg.norm(quat)), touching=touching,
                      obstacle=obstacle)
        return _edited(robot, robot._editable("attach"), edit)
    if not isinstance(obstacle, str):
        raise InputTypeError(f"obstacle must be the name of a geom of the world (str) or a profrobot Obstacle; "
                             f"got {type(obstacle).__name__}")
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, obstacle)
    if g < 0:
        fixed = [n for i, n in enumerate(_names(m, mujoco.mjtObj.mjOBJ_GEOM, m.ngeom))
                 if n and m.body_weldid[m.geom_bodyid[i]] == 0]
        raise InputError(f"obstacle={obstacle!r} is not a geom of {robot.name}; its named fixed geoms: "
                         f"{', '.join(fixed) or 'none'}")
    if m.body_weldid[m.geom_bodyid[g]] != 0:
        raise InputError(f"obstacle={obstacle!r} moves (with the robot, or on a family's scene joints); attach a "
                         "fixed geom of the world (pin a family with robot.at(layout) first)")
    if m.geom_type[g] in (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD):
        raise InputError(f"obstacle={obstacle!r} is a plane or height field; it cannot be held")
    if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, obstacle) >= 0:
        raise InputError(f"obstacle={obstacle!r}: a body has that name already; rename the geom")
    if at is None:
        raise InputError("at is required: the robot's pose at the grasp (the object keeps its place there)")
    d = _kinematics(robot, at, "at")
    xq = np.zeros(4)
    mujoco.mju_mat2Quat(xq, d.geom_xmat[g])
    body_p, body_q = _compose(*_inverse(d.xpos[b], d.xquat[b]), d.geom_xpos[g], xq)
    mp, mq = _inverse(*_mesh_frame(m, g))
    edit = Attach(obstacle, to, tuple(body_p), tuple(body_q), size=tuple(m.geom_size[g]), geom_pos=tuple(mp),
                  geom_quat=tuple(mq), touching=touching)
    return _edited(robot, robot._editable("attach"), edit)


def _placed(robot, at: npt.ArrayLike, b: int, g: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Body ``b``'s world position (3,) and quaternion (4,) at pose ``at`` by the core's forward
    kinematics (no compile), and the arrays' row of geom ``g``."""
    xpos, xquat = robot.core.body_frames(_one_pose(robot, at, "at"), b, threads=1)
    return xpos[0], xquat[0], int(np.searchsorted(robot._arrays["geom_id"], g))


def _held(robot, name: str, g: int, b: int, at: npt.ArrayLike | None, touching: tuple[str, ...]):
    """:func:`attach` of the world primitive ``g`` to body ``b`` without compiling: where the
    robot holds it at ``at``, by the core's forward kinematics and the geom's row."""
    if at is None:
        raise InputError("at is required: the robot's pose at the grasp (the object keeps its place there)")
    xpos, xquat, r = _placed(robot, at, b, g)
    body_p, body_q = _compose(*_inverse(xpos, xquat), robot._arrays["geom_pos"][r], robot._arrays["geom_quat"][r])
    edit = Attach(name, robot.body_names[b], tuple(map(float, body_p)), tuple(map(float, body_q)),
                  size=tuple(map(float, robot._arrays["geom_size"][r])), touching=touching)
    return _world.with_held(robot, edit, g, tuple(robot.body_names.index(t) for t in touching), robot.name)


def detach(robot, name: str, *, at: npt.ArrayLike):
    """``robot`` with the held object ``name`` left in the world where it is at pose ``at``
    (module docs; :meth:`Robot.detach`)."""
    if not isinstance(name, str):
        raise InputTypeError(f"name must be the held object's name (str); got {type(name).__name__}")
    put = _world.put_geom(robot, name)
    if put is not None:   # a held primitive: written into the arrays (robot/world.py), no compile
        b, g = put
        xpos, xquat, r = _placed(robot, at, b, g)
        pos, quat = _compose(xpos, xquat, robot._arrays["geom_pos"][r], robot._arrays["geom_quat"][r])
        edit = Detach(name, tuple(map(float, pos)), tuple(map(float, quat)),
                      size=tuple(map(float, robot._arrays["geom_size"][r])))
        return _world.with_put(robot, edit, b, g, robot.name)
    m = robot.mj_model
    spec = robot._editable("detach")
    # (the compiler may fuse a held object's body into its parent: the spec says what is held)
    held = [b.name for b in spec.bodies if b.name and not b.joints and len(b.geoms) == 1 and b.geoms[0].name == b.name
            and b.parent.name != "world"]
    if name not in held:
        raise InputError(f"name={name!r} is not an object {robot.name} holds; it holds: {', '.join(held) or 'nothing'}")
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
    d = _kinematics(robot, at, "at")
    xq = np.zeros(4)
    mujoco.mju_mat2Quat(xq, d.geom_xmat[g])
    pos, quat = _compose(d.geom_xpos[g], xq, *_inverse(*_mesh_frame(m, g)))
    edit = Detach(name, tuple(pos), tuple(quat), size=tuple(m.geom_size[g]))
    return _edited(robot, spec, edit)
