"""Forward kinematics against MuJoCo's mj_kinematics (acceptance 2)."""

import mujoco
import numpy as np
import pytest

import profrobot
from conftest import scene


@pytest.mark.parametrize("name", profrobot.scenes.names())
def test_fk_matches_mujoco(name):
    robot = scene(name)
    m = robot.mj_model
    d = mujoco.MjData(m)
    poses = profrobot.sample_poses(robot, 200, 3)
    # Also beyond the limits: FK itself must not care.
    poses = np.concatenate([poses, poses * 1.5])
    xpos, xquat = robot.core.forward_kinematics(poses)
    for i, q in enumerate(poses):
        d.qpos[robot.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        np.testing.assert_allclose(xpos[i], d.xpos, atol=1e-5)
        # q and -q are the same rotation.
        sign = np.sign(np.sum(xquat[i] * d.xquat, axis=1, keepdims=True))
        np.testing.assert_allclose(xquat[i] * sign, d.xquat, atol=1e-5)
