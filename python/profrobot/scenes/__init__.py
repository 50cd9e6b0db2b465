"""Named benchmark scenes, like the paper's six: a Menagerie robot plus static obstacles, built
with ``mujoco.MjSpec``. ``load(name)`` returns a :class:`profrobot.Robot`.

| name            | robot              | static scene                                   | tests              |
|-----------------|--------------------|------------------------------------------------|--------------------|
| panda_blocks    | Franka Panda + hand| floor, three blocks                            | self + scene       |
| ur5e_wall_box   | UR5e               | floor, a wall beside it, a box in front        | self + scene (paper's sim-to-real layout) |
| shadow_hand     | Shadow Hand (right)| none                                           | self only, 24 joints |
| xarm7_table     | xArm7 + gripper    | floor, table top, a cylindrical post           | self + scene       |
| vx300s_clutter  | ViperX 300 S       | floor, sphere, capsule, cylinder               | primitives         |
| panda_shelf     | Panda + hand       | floor, two-shelf rack, a mesh wedge            | mesh obstacle      |

The point-cloud bench's true scene (not in ``names()``: its objects are what a depth camera
sees, :mod:`profrobot.robot.pointcloud`), ``panda_clutter()``: the Panda on the floor among seven objects,
four of them meshes (a crate, a rock, a wedge, an overhead beam), a ball, a can and a post.

Families of scenes (:mod:`profrobot.robot.family`: obstacles on scene joints δ), ``family_names()``:

| name                | robot        | movable obstacles                                                  |
|---------------------|--------------|--------------------------------------------------------------------|
| panda_blocks_moving | Panda + hand | panda_blocks' three blocks, each ±15 cm in x and y, ±45° of yaw (δ: 9) |
| vx300s_clutter_moving | ViperX 300 S | a ball (x, y, z), a floating bar (capsule: x, y, z, yaw), a can (cylinder: x, y), a crate (box: x, y, yaw); ±10–15 cm, ±45° (δ: 12) |
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

import math

from ..robot.family import Moves
from ..robot import Box, Capsule, Cylinder, Mesh, Obstacle, Plane, Robot, Sphere
from ..errors import InputError

FLOOR = Plane(pos=(0, 0, 0), name="floor", rgba=(0.9, 0.9, 0.9, 1))


def _scene(menagerie: str, entry: str, obstacles: list[Obstacle], name: str) -> Robot:
    return Robot.from_menagerie(menagerie, entry).with_obstacles(obstacles, name=name)


def panda_blocks() -> Robot:
    return _scene("franka_emika_panda", "panda", [
        FLOOR,
        Box(pos=(0.55, 0.0, 0.10), half_size=(0.10, 0.10, 0.10), name="block_front"),
        Box(pos=(0.30, 0.45, 0.15), half_size=(0.08, 0.08, 0.15), name="block_left"),
        Box(pos=(0.25, -0.45, 0.06), half_size=(0.15, 0.10, 0.06), name="block_right"),
    ], "panda_blocks")


def box_mesh(half_size) -> np.ndarray:
    """The 8 corners (8, 3) of a box of ``half_size``: a box that collides as a convex mesh."""
    h = np.asarray(half_size, dtype=float)
    return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h


def ur5e_wall_box() -> Robot:
    # The wall and box are 8-vertex meshes, not MuJoCo boxes: MuJoCo 4.0's capsule-box collider
    # reports no contact when a capsule (the UR5e's links) pierces a box with both ends outside,
    # so box obstacles would make MuJoCo, our reference, wrong (tests pin that case).
    return _scene("universal_robots_ur5e", "ur5e", [
        FLOOR,
        Mesh(pos=(0.0, 0.65, 0.6), vertices=box_mesh((1.0, 0.02, 0.6)), name="wall"),
        Mesh(pos=(0.45, -0.1, 0.12), vertices=box_mesh((0.12, 0.12, 0.12)), name="box"),
    ], "ur5e_wall_box")


def shadow_hand() -> Robot:
    robot = Robot.from_menagerie("shadow_hand", "right_hand")
    robot.name = "shadow_hand"
    return robot


def xarm7_table() -> Robot:
    return _scene("ufactory_xarm7", "xarm7", [
        FLOOR,
        Box(pos=(0.55, 0.0, 0.20), half_size=(0.25, 0.40, 0.02), name="table_top"),
        Cylinder(pos=(0.30, -0.35, 0.35), radius=0.04, half_length=0.35, name="post"),
    ], "xarm7_table")


def vx300s_clutter() -> Robot:
    return _scene("trossen_vx300s", "vx300s", [
        FLOOR,
        Sphere(pos=(0.40, 0.10, 0.20), radius=0.08, name="ball"),
        Capsule(pos=(0.25, -0.30, 0.25), quat=(0.7071068, 0.7071068, 0, 0), radius=0.04, half_length=0.15, name="bar"),
        Cylinder(pos=(-0.10, 0.35, 0.15), radius=0.06, half_length=0.15, name="can"),
    ], "vx300s_clutter")


def panda_shelf() -> Robot:
    wedge = np.array([[-0.1, -0.1, 0], [0.1, -0.1, 0], [0.1, 0.1, 0], [-0.1, 0.1, 0], [-0.1, -0.1, 0.15], [-0.1, 0.1, 0.15]])
    return _scene("franka_emika_panda", "panda", [
        FLOOR,
        Box(pos=(0.60, 0.0, 0.30), half_size=(0.15, 0.35, 0.015), name="shelf_low"),
        Box(pos=(0.60, 0.0, 0.65), half_size=(0.15, 0.35, 0.015), name="shelf_high"),
        Box(pos=(0.60, 0.36, 0.40), half_size=(0.15, 0.015, 0.40), name="shelf_side"),
        Mesh(pos=(0.0, -0.5, 0.0), vertices=wedge, name="wedge"),
    ], "panda_shelf")


def _rock(radius: float, seed: int) -> np.ndarray:
    """An irregular convex "rock": 40 points on an ellipsoid, jittered (seeded)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(40, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * radius * np.array([1.0, 0.8, 0.6]) * rng.uniform(0.85, 1.0, size=(40, 1))


def panda_clutter() -> Robot:
    """The Panda on the floor among seven objects nobody modelled for it (the point-cloud
    bench's ground truth): meshes (a yawed crate, a rock, a wedge, an overhead beam) and
    primitives (a ball, a can, a post)."""
    wedge = np.array([[-0.08, -0.1, 0], [0.08, -0.1, 0], [0.08, 0.1, 0], [-0.08, 0.1, 0], [-0.08, -0.1, 0.14], [-0.08, 0.1, 0.14]])
    return _scene("franka_emika_panda", "panda", [
        FLOOR,
        Mesh(pos=(0.50, 0.30, 0.08), quat=(math.cos(0.35 / 2), 0, 0, math.sin(0.35 / 2)), vertices=box_mesh((0.12, 0.09, 0.08)),
             name="crate"),
        Mesh(pos=(0.38, 0.02, 0.05), vertices=_rock(0.07, 7), name="rock"),
        Mesh(pos=(0.62, -0.28, 0.0), vertices=wedge, name="wedge"),
        Mesh(pos=(0.55, 0.0, 0.62), vertices=box_mesh((0.05, 0.45, 0.03)), name="beam"),
        Sphere(pos=(0.68, 0.05, 0.07), radius=0.07, name="ball"),
        Cylinder(pos=(0.40, -0.25, 0.10), radius=0.045, half_length=0.10, name="can"),
        Capsule(pos=(0.22, 0.42, 0.30), radius=0.03, half_length=0.27, name="post"),
    ], "panda_clutter")


#: how panda_blocks_moving's blocks move: ±15 cm along x and y, ±45° about z
BLOCK_MOVES = Moves(x=(-0.15, 0.15), y=(-0.15, 0.15), yaw=(-math.pi / 4, math.pi / 4))


def panda_blocks_moving() -> Robot:
    """panda_blocks as a family: each block moves ±15 cm in x and y and ±45° in yaw (9 scene
    joints, ``block_front_x`` ... ``block_right_yaw``); δ = 0 is panda_blocks itself."""
    return _scene("franka_emika_panda", "panda", [
        FLOOR,
        Box(pos=(0.55, 0.0, 0.10), half_size=(0.10, 0.10, 0.10), name="block_front", moves=BLOCK_MOVES),
        Box(pos=(0.30, 0.45, 0.15), half_size=(0.08, 0.08, 0.15), name="block_left", moves=BLOCK_MOVES),
        Box(pos=(0.25, -0.45, 0.06), half_size=(0.15, 0.10, 0.06), name="block_right", moves=BLOCK_MOVES),
    ], "panda_blocks_moving")


def vx300s_clutter_moving() -> Robot:
    """vx300s_clutter as a family of four mixed obstacles (12 scene joints): the ball moves in x,
    y, z; the bar (a horizontal capsule) in x, y, z and yaw; the can (a vertical cylinder: its yaw
    would change nothing) in x and y; a crate (a box) in x, y and yaw."""
    xy = (-0.12, 0.12)
    return _scene("trossen_vx300s", "vx300s", [
        FLOOR,
        Sphere(pos=(0.40, 0.10, 0.20), radius=0.08, name="ball", moves=Moves(x=xy, y=xy, z=(-0.10, 0.10))),
        Capsule(pos=(0.25, -0.30, 0.25), quat=(0.7071068, 0.7071068, 0, 0), radius=0.04, half_length=0.15, name="bar",
                moves=Moves(x=xy, y=xy, z=(-0.10, 0.10), yaw=(-math.pi / 4, math.pi / 4))),
        Cylinder(pos=(-0.10, 0.35, 0.15), radius=0.06, half_length=0.15, name="can", moves=Moves(x=xy, y=xy)),
        Box(pos=(0.30, 0.45, 0.08), half_size=(0.09, 0.06, 0.08), name="crate",
            moves=Moves(x=xy, y=xy, yaw=(-math.pi / 4, math.pi / 4))),
    ], "vx300s_clutter_moving")


_FAMILIES: dict[str, Callable[[], Robot]] = {f.__name__: f for f in (panda_blocks_moving, vx300s_clutter_moving)}

_BUILDERS: dict[str, Callable[[], Robot]] = {
    f.__name__: f for f in (panda_blocks, ur5e_wall_box, shadow_hand, xarm7_table, vx300s_clutter, panda_shelf)
}


def names() -> list[str]:
    """Every bundled scene name."""
    return list(_BUILDERS)


def family_names() -> list[str]:
    """Every bundled family of scenes (obstacles on scene joints, :mod:`profrobot.robot.family`)."""
    return list(_FAMILIES)


def load(name: str) -> Robot:
    """Builds the bundled scene or family of scenes ``name`` (see the tables in this module's
    docstring)."""
    builder = _BUILDERS.get(name) or _FAMILIES.get(name)
    if builder is None:
        raise InputError(f"unknown scene {name!r}; bundled scenes: {', '.join(_BUILDERS)}; families: "
                         f"{', '.join(_FAMILIES)}")
    return builder()
