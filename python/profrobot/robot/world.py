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
from .sources import _Mjcf
from .state import with_core

__all__ = ["WorldGeoms", "world_geoms", "spec_names", "fits", "with_primitives"]

#: the obstacle types written without compiling (primitives: MuJoCo keeps their frames as given)
PRIMITIVES = (Box, Sphere, Capsule, Cylinder, Plane)


@dataclass(frozen=True)
class WorldGeoms:
    """What a geom added to the world of a robot's spec gets from MuJoCo, and what is taken.

    ``count``: geoms on the world body (MuJoCo ids ``0 .. count - 1``, visual ones included);
    ``contype`` / ``conaffinity`` / ``margin``: the spec's default geom's; ``override``: the model
    overrides contact margins; ``names``: every geom and body name (obstacle names must be new)."""

    count: int
    contype: int
    conaffinity: int
    margin: float
    override: bool
    names: frozenset[str]


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
        count=int(m.body_geomnum[0]), contype=int(default.contype), conaffinity=int(default.conaffinity),
        margin=float(default.margin), override=bool(m.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE),
        names=spec_names(spec))
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
    derived._world_geoms = replace(world, count=world.count + len(obstacles),
                                   names=world.names | {ob.name for ob in obstacles if ob.name})
    return derived
