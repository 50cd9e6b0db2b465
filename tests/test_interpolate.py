"""SO(2) interpolation: shortest arcs for continuous joints, straight segments otherwise."""

import mujoco
import numpy as np

import profrobot
from profrobot import Robot


def continuous_robot() -> Robot:
    xml = """<mujoco><compiler angle="radian"/><worldbody><body><joint name="spin" axis="0 0 1" limited="false"/><geom size="0.1"/>
        <body pos="0 0 0.3"><joint name="bend" axis="1 0 0" range="-1 1"/><geom size="0.1"/></body></body>
        </worldbody></mujoco>"""
    return Robot.from_spec(mujoco.MjSpec.from_string(xml))


def test_continuous_joint_takes_the_short_way_and_limited_goes_straight():
    robot = continuous_robot()
    assert list(robot.continuous) == [True, False]
    path = profrobot.interpolate(robot, [3.0, -1.0], [-3.0, 1.0], 101)
    assert path.shape == (101, 2)
    steps = np.diff(path, axis=0)
    np.testing.assert_allclose(steps[:, 0], (2 * np.pi - 6.0) / 100)  # through pi, not through 0
    np.testing.assert_allclose(steps[:, 1], 0.02)
    np.testing.assert_allclose(path[-1], [-3.0 + 2 * np.pi, 1.0])
    assert (path[:, 1] >= -1).all() and (path[:, 1] <= 1).all()


def test_batched_interpolation_matches_single(panda):
    a = profrobot.sample_poses(panda, 5, seed=1)
    b = profrobot.sample_poses(panda, 5, seed=2)
    batch = profrobot.interpolate(panda, a, b, 17)
    assert batch.shape == (5, 17, 9)
    for i in range(5):
        np.testing.assert_allclose(batch[i], profrobot.interpolate(panda, a[i], b[i], 17))
    np.testing.assert_allclose(batch[:, 0], a)
    np.testing.assert_allclose(batch[:, -1], b)
