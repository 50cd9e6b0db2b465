"""Obstacles added to a built robot without compiling MuJoCo: the geoms MuJoCo's compiler would
make of them written straight into the core's flat arrays (:mod:`profrobot.robot.arrays`), the
robot's own shapes shared (``RobotModel.rebuilt``). A scene of a dozen boxes on a built Panda costs
about a millisecond instead of a compile (~100 ms); the MuJoCo model is compiled on first use of
``robot.mj_model`` / ``robot.spec`` and checked against the robot's fingerprint there
(:func:`profrobot.robot.state.restore`, :class:`~profrobot.errors.RobotMismatchError` on any
difference), so a cross-check always compares with what MuJoCo makes of the same source.

What MuJoCo's compiler does with a primitive geom added to the world body (``spec.worldbody.
add_geom``), and so what is written here:

- its id follows the world's other geoms (visual ones included): every later geom's id, in the
  arrays and in explicit ``<pair>``s, moves up by one;
- its frame is its ``pos`` and unit ``quat`` in the world; its size MuJoCo's (box half extents,
  ``[r, 0, 0]``, ``[r, h, 0]``, a plane's ``[0, 0, 0.05]``);
- ``contype``, ``conaffinity`` and ``margin`` are the spec's default geom's, the margin raised to the
  robot's safety margin (:class:`~profrobot.robot.margin.ObstacleMargin`);
- a geom with ``contype`` and ``conaffinity`` both 0 collides with nothing: no row, its id taken.

Meshes (MuJoCo recentres a mesh on its inertial frame), moving obstacles (scene joints), a model
that overrides contact margins, and robots whose source cannot rebuild them exactly take the
compile path. Base layer: numpy and mujoco.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np

from .arrays import label_fingerprint
from .margin import ObstacleMargin
from .obstacles import Box, Capsule, Cylinder, Obstacle, Plane, Sphere
from .poses import share_bounds
from .sources import _Mjcf
from .state import with_core

__all__ = ["WorldGeoms", "world_geoms", "spec_names", "fits", "with_primitives", "held_geom", "with_held",
           "put_geom", "with_put", "frame"]

#: the obstacle types written without compiling (primitives: MuJoCo keeps their frames as given)
PRIMITIVES = (Box, Sphere, Capsule, Cylinder, Plane)
#: the geom types a held object is moved onto a body without compiling
_HELD_TYPES = tuple(int(t) for t in (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE,
                                     mujoco.mjtGeom.mjGEOM_ELLIPSOID, mujoco.mjtGeom.mjGEOM_CYLINDER,
                                     mujoco.mjtGeom.mjGEOM_BOX))


@dataclass(frozen=True)
class WorldGeoms:
    """What a geom added to the world of a robot's spec gets from MuJoCo, and what is taken.

    ``contype`` / ``conaffinity`` / ``margin``: the spec's default geom's; ``override``: the model
    overrides contact margins; ``names``: every geom and body name (obstacle names must be new);
    ``geom_names``: every geom's name in MuJoCo's id order ('' where it has none), visual ones
    included; ``body_geoms``: how many geoms each body has (MuJoCo's ``body_geomnum``);
    ``sites``: every named site as ``(name, body id, pos, quat)`` (the frames ``ik`` and
    ``plan_cartesian`` move, found without compiling: :func:`frame`)."""

    contype: int
    conaffinity: int
    margin: float
    override: bool
    names: frozenset[str]
    geom_names: tuple[str, ...]
    body_geoms: tuple[int, ...]
    sites: tuple[tuple[str, int, tuple[float, ...], tuple[float, ...]], ...] = ()

    @property
    def count(self) -> int:
        """Geoms on the world body (MuJoCo ids ``0 .. count - 1``)."""
        return self.body_geoms[0]


def spec_names(spec: mujoco.MjSpec) -> frozenset[str]:
    """Every geom and body name of ``spec`` (an obstacle's name must be none of them)."""
    return frozenset({g.name for g in spec.geoms if g.name} | {b.name for b in spec.bodies if b.name})


def world_geoms(robot: Any) -> WorldGeoms:
    """The robot's :class:`WorldGeoms`: carried by robots this module made, else read from its
    compiled model and spec (once)."""
    known = robot.__dict__.get("_world_geoms")
    if known is not None:
        return known
    m, spec = robot.mj_model, robot.spec
    assert spec is not None  # fits(): the robot's source rebuilds it exactly
    default = spec.default.geom
    known = WorldGeoms(
        contype=int(default.contype), conaffinity=int(default.conaffinity),
        margin=float(default.margin), override=bool(m.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE),
        names=spec_names(spec),
        geom_names=tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(m.ngeom)),
        body_geoms=tuple(int(n) for n in m.body_geomnum),
        sites=tuple((n, int(m.site_bodyid[i]), tuple(map(float, m.site_pos[i])), tuple(map(float, m.site_quat[i])))
                    for i, n in enumerate(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SITE, i) for i in range(m.nsite))
                    if n))
    robot.__dict__["_world_geoms"] = known
    return known


def _exact_source(robot: Any) -> bool:
    """Whether the robot's source rebuilds its model exactly (an MJCF or URDF read from files).
    The files are read here, once per robot (as its first pickle would read them): a robot derived
    without compiling compiles its MuJoCo model later, when they may be gone."""
    if robot._source is None or not isinstance(robot._source.root, (str, _Mjcf)):
        return False
    try:
        robot._source = robot._source.loaded()
    except OSError:
        return False
    root = robot._source.root
    return isinstance(root, _Mjcf) and root.exact


def _rows(world: WorldGeoms, obstacles: tuple[Obstacle, ...], margin: float) -> dict[str, np.ndarray]:
    """The arrays' geom rows of ``obstacles`` (MuJoCo ids from ``world.count`` on): none where the
    spec's default geom collides with nothing."""
    geoms = [ob.geom() for ob in obstacles]   # validated exactly as add_to validates them
    if not (world.contype or world.conaffinity):
        geoms = []
    n = len(geoms)
    g_margin = max(world.margin, margin) if margin > 0 else world.margin
    return dict(
        geom_id=np.arange(world.count, world.count + n, dtype=np.int32),
        geom_type=np.asarray([int(g["type"]) for g in geoms], dtype=np.int32), geom_body=np.zeros(n, dtype=np.int32),
        geom_pos=np.asarray([g["pos"] for g in geoms], dtype=np.float64).reshape(-1, 3),
        geom_quat=np.asarray([g["quat"] for g in geoms], dtype=np.float64).reshape(-1, 4),
        geom_size=np.asarray([g["size"] for g in geoms], dtype=np.float64).reshape(-1, 3),
        geom_contype=np.full(n, world.contype, dtype=np.uint32),
        geom_conaffinity=np.full(n, world.conaffinity, dtype=np.uint32),
        geom_margin=np.full(n, g_margin, dtype=np.float64), geom_mesh=np.full(n, -1, dtype=np.int32))


def fits(robot: Any, obstacles: tuple[Obstacle, ...]) -> bool:
    """Whether :func:`with_primitives` can add ``obstacles`` to ``robot`` (module docs): static
    primitives, on a robot whose source rebuilds it exactly and whose model does not override
    contact margins."""
    if not obstacles or not _exact_source(robot):
        return False
    if any(type(ob) not in PRIMITIVES or ob.moves is not None for ob in obstacles):
        return False
    return not world_geoms(robot).override


def with_primitives(robot: Any, obstacles: tuple[Obstacle, ...], name: str) -> Any:
    """``robot.with_obstacles(obstacles)`` without compiling MuJoCo (module docs), for obstacles
    that :func:`fits` accepts, their names checked by the caller."""
    world = world_geoms(robot)
    rows = _rows(world, obstacles, robot.margin)
    old = robot._arrays
    arrays: dict[str, Any] = dict(old)

    def shift(ids: np.ndarray) -> np.ndarray:
        """Every geom after the world's moves up by the obstacles' ids (in the rows, in <pair>s)."""
        return np.where(ids >= world.count, ids + len(obstacles), ids).astype(np.int32)

    arrays["pair_geom"] = shift(old["pair_geom"])
    at = int(np.searchsorted(old["geom_id"], world.count))   # the rows of the world's geoms come first
    for key, new in rows.items():
        base = shift(old[key]) if key == "geom_id" else old[key]
        arrays[key] = np.ascontiguousarray(np.concatenate([base[:at], new, base[at:]]))
    edits: tuple = obstacles
    if robot.margin > 0:  # as Robot._derived: the source's new obstacles get the margin too
        edits = edits + (ObstacleMargin(robot.margin),)

    derived = with_core(robot, arrays, robot.core.rebuilt(arrays))
    derived.name = name
    share_bounds(robot, derived)   # the same joints and limits
    plain = {k: v for k, v in arrays.items() if not k.startswith("cloud_")}
    derived.geometry_fingerprint = (derived.fingerprint if len(plain) == len(arrays)
                                    else label_fingerprint(robot.joint_names, plain, robot.scene_joints))
    derived.layout = None
    derived.family_fingerprint = None
    derived._mj_model = None   # compiled on first use, and checked against the fingerprint
    derived._spec = None
    derived._spec_lost = None
    derived._source = robot._source.then(edits)
    # the MuJoCo model is compiled from the nearest spec at hand (state.restore), else the source
    if robot._spec is not None:
        derived._spec_from = (robot._spec, edits)
    elif "_spec_from" in robot.__dict__:
        spec, before = robot.__dict__["_spec_from"]
        derived._spec_from = (spec, before + edits)
    derived._world_geoms = replace(
        world, names=world.names | {ob.name for ob in obstacles if ob.name},
        geom_names=world.geom_names[:world.count] + tuple(ob.name or "" for ob in obstacles) + world.geom_names[world.count:],
        body_geoms=(world.count + len(obstacles), *world.body_geoms[1:]))
    return derived


# ---- a world geom taken onto a body of the robot (Robot.attach) -------------------------------------
#
# What MuJoCo's compiler makes of ``grasp.Attach`` (the geom deleted from the world, a body ``name``
# added as the last child of ``to`` at ``pos`` / ``quat``, the geom on it at its origin), and so
# what is written here:
#
# - bodies are numbered depth first: the new body's id is one past the last body of ``to``'s
#   subtree, and every later body id (parents, welds, joints, geoms, excludes) moves up by one;
#   its parent is ``to``, its weld ``to``'s weld (it has no joint), its frame ``pos`` and ``quat``
#   normalised as the compiler normalises it (each component divided by the 2-norm);
# - geoms are numbered body by body: the geom leaves the world's ids (later ids down by one) and
#   takes the id after every geom of the bodies before the new one; its frame in the new body is
#   the origin, its size, type, contype, conaffinity and margin the world geom's row;
# - ``touching``: an exclude of (new body, body) each, the lower id first, all excludes sorted by
#   MuJoCo's signature ``(body1 << 16) + body2`` (a repeated one once).


def held_geom(robot: Any, name: str) -> int | None:
    """The MuJoCo id of the geom ``name`` when :func:`with_held` can attach it without compiling:
    a primitive (not a plane) on the world body with a row in the arrays, on a robot whose source
    rebuilds it exactly, with no point cloud, scene joints or margin override; else None."""
    if robot.cloud is not None or robot.scene_joints or not _exact_source(robot):
        return None
    world = world_geoms(robot)
    if world.override or name not in world.geom_names[:world.count]:
        return None
    g = world.geom_names.index(name)
    ids = robot._arrays["geom_id"]
    r = int(np.searchsorted(ids, g))
    if r == len(ids) or ids[r] != g or int(robot._arrays["geom_type"][r]) not in _HELD_TYPES:
        return None
    return g


def _unit(q: np.ndarray) -> np.ndarray:
    """``q`` normalised as MuJoCo's compiler normalises a body's quaternion: left as it is when
    its 2-norm (summed in order) is within ``mjMINVAL`` (1e-15) of 1, else each component divided
    by it (checked against the compiler on 2 000 quaternions, half of them near unit)."""
    q = np.asarray(q, dtype=np.float64)
    norm = float(np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]))
    return q.copy() if abs(norm - 1.0) <= 1e-15 else np.array([float(x) / norm for x in q])


def with_held(robot: Any, edit: Any, g: int, touching: tuple[int, ...], name: str) -> Any:
    """``robot.attach`` of the world geom ``g`` (:func:`held_geom`) as the ``grasp.Attach``
    ``edit`` says, without compiling (the notes above); ``touching``: body ids."""
    world = world_geoms(robot)
    old = robot._arrays
    parent = old["body_parent"]
    to = robot.body_names.index(edit.to)
    last = to
    for b in range(to + 1, len(parent)):      # (depth first: the subtree of `to` is contiguous)
        if parent[b] < to or parent[b] > last:
            break
        last = b
    new_body = last + 1
    held_id = sum(world.body_geoms[:new_body]) - 1   # (the geom has left the world, before it)

    def body_ids(ids: np.ndarray) -> np.ndarray:
        return np.where(ids >= new_body, ids + 1, ids).astype(np.int32)

    arrays: dict[str, Any] = dict(old)
    arrays["body_parent"] = _insert_row(body_ids(parent), new_body, to)
    weld = body_ids(old["body_weld"])
    arrays["body_weld"] = _insert_row(weld, new_body, weld[to])
    arrays["body_pos"] = _insert_row(old["body_pos"], new_body, edit.pos)
    arrays["body_quat"] = _insert_row(old["body_quat"], new_body, _unit(np.asarray(edit.quat)))
    arrays["jnt_body"] = body_ids(old["jnt_body"])
    names = _move_geom(old, arrays, world, g, held_id, body_ids, geom_body=new_body, geom_pos=np.zeros(3),
                       geom_quat=np.array([1.0, 0.0, 0.0, 0.0]))
    excl = body_ids(old["exclude"])
    extra = np.sort(np.array([[new_body, int(body_ids(np.array([t]))[0])] for t in touching],
                             dtype=np.int32).reshape(-1, 2), axis=1)    # (MuJoCo signs a pair lower id first)
    sig = np.unique(np.concatenate([excl, extra]).astype(np.int64) @ np.array([1 << 16, 1]))   # (sorted by it)
    arrays["exclude"] = np.stack([sig >> 16, sig & 0xFFFF], axis=1).astype(np.int32)
    body_names = robot.body_names[:new_body] + [edit.name] + robot.body_names[new_body:]
    counts = list(world.body_geoms)
    counts[0] -= 1
    counts.insert(new_body, 1)
    sites = tuple((n, b + (b >= new_body), p, q) for n, b, p, q in world.sites)
    return _edited(robot, arrays, edit, name, body_names,
                   replace(world, names=world.names | {edit.name}, geom_names=names, body_geoms=tuple(counts),
                           sites=sites))


def _insert_row(a: np.ndarray, i: int, row: Any) -> np.ndarray:
    """``a`` (N, ...) with ``row`` inserted before row ``i``, in ``a``'s dtype, contiguous (what
    ``np.insert(a, i, row, axis=0)`` gives, without its ~10 µs of argument handling: an attach
    inserts 18 rows)."""
    out = np.empty((len(a) + 1, *a.shape[1:]), dtype=a.dtype)
    out[:i], out[i], out[i + 1:] = a[:i], row, a[i:]
    return out


def _move_geom(old: dict, arrays: dict, world: WorldGeoms, g: int, new_id: int, body_ids: Any,
               **values: Any) -> tuple[str, ...]:
    """Into ``arrays``: the geom row of MuJoCo id ``g`` moved to id ``new_id`` with ``values``
    (its body, frame, ...), every other geom renumbered as MuJoCo numbers them (down by one
    after ``g``, then up by one from ``new_id``, in the rows and in ``<pair>``s) and every row's
    body by ``body_ids``. Returns the geom names in the new order."""
    def geom_ids(ids: np.ndarray) -> np.ndarray:
        a = ids - (ids > g)
        return np.where(ids == g, new_id, np.where(a >= new_id, a + 1, a)).astype(np.int32)

    r = int(np.searchsorted(old["geom_id"], g))
    row = {k: old[k][r] for k in old if k.startswith("geom_")}
    row.update(geom_id=new_id, **values)
    keep = np.arange(len(old["geom_id"])) != r
    ids = geom_ids(old["geom_id"][keep])
    at = int(np.searchsorted(ids, new_id))
    for key, value in row.items():
        rest = old[key][keep]
        if key == "geom_id":
            rest = ids
        elif key == "geom_body":
            rest = body_ids(rest)
        arrays[key] = _insert_row(rest, at, value)
    arrays["pair_geom"] = geom_ids(old["pair_geom"]) if len(old["pair_geom"]) else old["pair_geom"]
    names = list(world.geom_names)
    names.insert(new_id, names.pop(g))
    return tuple(names)


def _edited(robot: Any, arrays: dict, edit: Any, name: str, body_names: list[str], world: WorldGeoms) -> Any:
    """The robot of ``arrays``, ``robot`` after the spec edit ``edit`` (carried in its source,
    with the margin as ``Robot._derived`` adds it), its MuJoCo model compiled on first use."""
    edits: tuple = (edit,)
    if robot.margin > 0:  # as Robot._derived
        edits = edits + (ObstacleMargin(robot.margin),)
    derived = with_core(robot, arrays, robot.core.rebuilt(arrays))
    derived.name = name
    derived.body_names = body_names
    derived.geometry_fingerprint = derived.fingerprint
    derived._mj_model = None
    derived._spec = None
    derived._spec_lost = None
    derived._source = robot._source.then(edits)
    if robot._spec is not None:
        derived._spec_from = (robot._spec, edits)
    elif "_spec_from" in robot.__dict__:
        spec, before = robot.__dict__["_spec_from"]
        derived._spec_from = (spec, before + edits)
    derived._world_geoms = world
    return derived


# ---- a held object left in the world (Robot.detach) --------------------------------------------------
#
# What MuJoCo's compiler makes of ``grasp.Detach`` (the held body and its excludes deleted, the geom
# added to the world at ``pos`` / ``quat``), the inverse of the above: every body id after the held
# one moves down by one (its excludes gone); the geom leaves its id (later ids down by one) and
# takes the id after the world's geoms (later ids up by one); its frame is ``pos`` and ``quat``
# normalised as the compiler normalises it, its margin raised to the robot's safety margin
# (``ObstacleMargin``: it is an obstacle again), the rest of its row kept.


def put_geom(robot: Any, name: str) -> tuple[int, int] | None:
    """``(body, geom)`` MuJoCo ids of the held object ``name`` when :func:`with_put` can leave it
    in the world without compiling: a leaf body without joints holding one primitive geom of its
    name (not in an explicit ``<pair>``), on a robot as :func:`held_geom` requires; else None."""
    if robot.cloud is not None or robot.scene_joints or not _exact_source(robot) or name not in robot.body_names:
        return None
    world = world_geoms(robot)
    a = robot._arrays
    b = robot.body_names.index(name)
    if (world.override or b == 0 or a["body_parent"][b] == 0 or world.body_geoms[b] != 1 or b in a["jnt_body"]
            or b in a["body_parent"][b + 1:]):
        return None
    g = sum(world.body_geoms[:b])
    if world.geom_names[g] != name or g in a["pair_geom"] or any(s_b == b for _, s_b, _, _ in world.sites):
        return None
    r = int(np.searchsorted(a["geom_id"], g))
    if r == len(a["geom_id"]) or a["geom_id"][r] != g or int(a["geom_type"][r]) not in _HELD_TYPES:
        return None
    return b, g


def with_put(robot: Any, edit: Any, b: int, g: int, name: str) -> Any:
    """``robot.detach`` of the held object on body ``b`` (geom ``g``, :func:`put_geom`) as the
    ``grasp.Detach`` ``edit`` says, without compiling (the notes above)."""
    world = world_geoms(robot)
    old = robot._arrays
    put_id = world.count                      # (the held geom is after the world's: removing it moves none)

    def body_ids(ids: np.ndarray) -> np.ndarray:
        return np.where(ids > b, ids - 1, ids).astype(np.int32)

    arrays: dict[str, Any] = dict(old)
    keep_body = np.arange(len(old["body_parent"])) != b
    arrays["body_parent"] = body_ids(old["body_parent"][keep_body])
    arrays["body_weld"] = body_ids(old["body_weld"][keep_body])
    arrays["body_pos"] = np.ascontiguousarray(old["body_pos"][keep_body])
    arrays["body_quat"] = np.ascontiguousarray(old["body_quat"][keep_body])
    arrays["jnt_body"] = body_ids(old["jnt_body"])
    margin = old["geom_margin"][int(np.searchsorted(old["geom_id"], g))]
    names = _move_geom(old, arrays, world, g, put_id, body_ids, geom_body=0,
                       geom_pos=np.asarray(edit.pos, dtype=np.float64), geom_quat=_unit(np.asarray(edit.quat)),
                       geom_margin=max(float(margin), robot.margin) if robot.margin > 0 else margin)
    excl = old["exclude"]
    excl = excl[~(excl == b).any(axis=1)] if len(excl) else excl
    arrays["exclude"] = np.ascontiguousarray(body_ids(excl)).reshape(-1, 2)
    body_names = robot.body_names[:b] + robot.body_names[b + 1:]
    counts = list(world.body_geoms)
    del counts[b]
    counts[0] += 1
    sites = tuple((n, s_b - (s_b > b), p, q) for n, s_b, p, q in world.sites)   # (none on the held body)
    return _edited(robot, arrays, edit, name, body_names,
                   replace(world, geom_names=names, body_geoms=tuple(counts), sites=sites))


def frame(robot: Any, name: str) -> tuple[int, np.ndarray, np.ndarray] | None:
    """``(body, pos (3,), quat (4,))`` of the site or body ``name`` of a robot derived here whose
    MuJoCo model is not compiled yet (``exact.ik.frame_of`` without a compile: sites first, then
    bodies, as there); None where the model is at hand, or ``name`` is neither (a geom's frame,
    or no frame: the caller asks the compiled model)."""
    world = robot.__dict__.get("_world_geoms")
    if world is None or robot._mj_model is not None:
        return None
    for site, b, pos, quat in world.sites:
        if site == name:
            return b, np.array(pos), np.array(quat)
    if name in world.names and name in robot.body_names:   # (a real name: not a placeholder "body7")
        return robot.body_names.index(name), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
    return None
