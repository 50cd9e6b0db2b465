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
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

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


_BUILDERS: dict[str, Callable[[], Robot]] = {
    f.__name__: f for f in (panda_blocks, ur5e_wall_box, shadow_hand, xarm7_table, vx300s_clutter, panda_shelf)
}


def names() -> list[str]:
    """Every bundled scene name."""
    return list(_BUILDERS)


def load(name: str) -> Robot:
    """Builds the bundled scene ``name`` (see the table in this module's docstring)."""
    try:
        builder = _BUILDERS[name]
    except KeyError:
        raise InputError(f"unknown scene {name!r}; bundled scenes: {', '.join(_BUILDERS)}") from None
    return builder()
