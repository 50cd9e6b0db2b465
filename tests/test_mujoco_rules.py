"""MuJoCo's candidate-pair rules, one small MJCF each, checked against mj_collision."""

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot import Robot


def robot_from_xml(body: str, extra: str = "", option: str = "") -> Robot:
    xml = f"<mujoco><compiler angle=\"radian\"/>{option}<worldbody>{body}</worldbody>{extra}</mujoco>"
    return Robot.from_spec(mujoco.MjSpec.from_string(xml), name="test")


# Three links on hinges about x, stacked along z; each carries a sphere of radius 0.06 at its
# origin, 0.1 apart: neighbours overlap (0.1 < 0.12), b1 and b3 are 0.2 apart at q = 0 but meet
# when the middle joint folds.
CHAIN = """
<body name="b1" pos="0 0 0.5"><joint name="j1" axis="1 0 0" range="-3 3"/><geom name="g1" size="0.06"/>
  <body name="b2" pos="0 0 0.1"><joint name="j2" axis="1 0 0" range="-3 3"/><geom name="g2" size="0.06"/>
    <body name="b3" pos="0 0 0.1"><joint name="j3" axis="1 0 0" range="-3 3"/><geom name="g3" size="0.06"/></body>
  </body>
</body>"""


def both(robot: Robot, pose) -> tuple[bool, bool]:
    pose = np.atleast_2d(np.asarray(pose, dtype=float))
    ours = profrobot.label_poses(robot, pose).collides[0]
    theirs = profrobot.mujoco_labels(robot, pose).collides[0]
    return bool(ours), bool(theirs)


def test_parent_child_pairs_are_filtered():
    robot = robot_from_xml(CHAIN)
    assert robot.core.npair == 1  # only b1-b3
    assert both(robot, [0, 0, 0]) == (False, False)
    # Folding j2 by ~2.6 rad brings b3 back onto b1.
    assert both(robot, [0, 2.6, 0]) == (True, True)


def test_filterparent_disabled_tests_neighbours():
    robot = robot_from_xml(CHAIN, option='<option><flag filterparent="disable"/></option>')
    assert robot.core.npair == 3
    assert both(robot, [0, 0, 0]) == (True, True)


def test_exclude_removes_a_body_pair():
    robot = robot_from_xml(CHAIN, extra='<contact><exclude body1="b1" body2="b3"/></contact>')
    assert robot.core.npair == 0
    assert both(robot, [0, 2.6, 0]) == (False, False)


def test_explicit_pair_is_tested_despite_filters_and_uses_its_margin():
    extra = '<contact><exclude body1="b1" body2="b3"/><pair geom1="g1" geom2="g2" margin="0.001"/></contact>'
    robot = robot_from_xml(CHAIN, extra=extra)
    assert robot.core.npair == 1 and robot.pair_margin[0] == pytest.approx(0.001)
    assert both(robot, [0, 0, 0]) == (True, True)


def test_contype_conaffinity_bitmasks():
    body = CHAIN.replace('name="g1" size="0.06"', 'name="g1" size="0.06" contype="2" conaffinity="2"')
    robot = robot_from_xml(body)
    assert robot.core.npair == 0
    assert both(robot, [0, 2.6, 0]) == (False, False)
    body = CHAIN.replace('name="g1" size="0.06"', 'name="g1" size="0.06" contype="2" conaffinity="1"')
    robot = robot_from_xml(body)  # g1's contype 2 & g3's conaffinity 1 = 0, but g3's 1 & g1's 1 != 0
    assert both(robot, [0, 2.6, 0]) == (True, True)


def test_parent_filter_does_not_apply_to_bodies_welded_to_world():
    body = """<body name="base" pos="0 0 0.4"><geom size="0.06"/>
        <body name="link" pos="0 0 0.1"><joint axis="1 0 0" range="-1 1"/><geom size="0.06"/></body></body>"""
    robot = robot_from_xml(body)
    assert robot.core.npair == 1
    assert both(robot, [0.0]) == (True, True)


def test_margin_makes_near_geoms_collide():
    body = """<geom type="plane" size="1 1 0.1" margin="0.02"/>
        <body pos="0 0 0.5"><joint type="slide" axis="0 0 1" range="-1 1"/><geom size="0.1"/></body>"""
    robot = robot_from_xml(body)
    # Sphere bottom at 0.5 - 0.39 - 0.1 = 0.01 m: inside the 0.02 m margin.
    assert both(robot, [-0.39]) == (True, True)
    # At 0.03 m it is outside.
    assert both(robot, [-0.37]) == (False, False)


def test_regression_capsule_piercing_a_thin_box_collides():
    """MuJoCo 4.0's capsule-box collider misses a capsule that passes through a box with both
    ends outside; we report the (geometrically certain) collision. Pinned so that a MuJoCo fix,
    or a change of ours, is noticed."""
    body = """<geom name="wall" type="box" size="1 0.02 0.6"/>
        <body><joint type="slide" axis="1 0 0" range="-1 1"/>
          <geom name="rod" type="capsule" size="0.03 0.3" quat="0.7071068 0.7071068 0 0"/></body>"""
    robot = robot_from_xml(body)
    labels = profrobot.label_poses(robot, [[0.0]], distance=True)
    assert labels.collides[0] and labels.min_distance[0] < -0.02
    assert not profrobot.mujoco_labels(robot, [[0.0]]).collides[0]
