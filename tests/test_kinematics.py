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


@pytest.mark.parametrize("name", profrobot.scenes.names())
def test_torch_fk_matches_mujoco(name):
    """The torch back end (profrobot.kinematics) reads the same flat arrays as the Rust core."""
    import torch

    from profrobot.kinematics.fk import Kinematics

    robot = scene(name)
    m = robot.mj_model
    d = mujoco.MjData(m)
    poses = profrobot.sample_poses(robot, 50, 4)
    poses = np.concatenate([poses, poses * 1.5])
    for dtype, tol in ((torch.float64, 1e-10), (torch.float32, 1e-5)):
        bp = Kinematics.from_robot(robot, dtype=dtype)(torch.as_tensor(poses, dtype=dtype))
        for i, q in enumerate(poses):
            d.qpos[robot.qpos_adr] = q
            mujoco.mj_kinematics(m, d)
            np.testing.assert_allclose(bp.pos[i].numpy(), d.xpos, atol=tol)
            np.testing.assert_allclose(bp.rot[i].numpy().reshape(-1, 9), d.xmat, atol=tol)


def test_torch_fk_gradient_matches_finite_differences(panda):
    import torch

    from profrobot.kinematics.fk import Kinematics

    kin = Kinematics.from_robot(panda, dtype=torch.float64)
    q = torch.as_tensor(profrobot.sample_poses(panda, 3, 5), dtype=torch.float64).requires_grad_()
    w = torch.randn(3, kin.nbody, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    f = lambda q: (kin(q).pos * w).sum() + kin(q).rot[..., 0, :].sum()
    assert torch.autograd.gradcheck(f, (q,), eps=1e-6, atol=1e-6)



@pytest.mark.parametrize("name", ["franka_emika_panda", "universal_robots_ur5e"])
def test_closed_form_fk_equals_autograd_fk(name):
    """Kinematics.fast (float64 recursion, backward written out: ∂R_b/∂θ_j = [ω]× R_b,
    ∂x_b/∂θ_j = ω × (x_b - p)) gives the poses and the joint gradients of the autograd FK."""
    import torch

    from profrobot.kinematics.fk import Kinematics

    robot = profrobot.Robot.from_menagerie(name)
    kin = Kinematics.from_robot(robot, dtype=torch.float64)
    assert kin._closed_form
    q = torch.as_tensor(np.random.default_rng(0).uniform(*robot.joint_limits.T, (5, robot.njoint)))
    q1, q2 = q.clone().requires_grad_(True), q.clone().requires_grad_(True)
    a, b = kin(q1), kin.fast(q2)
    torch.testing.assert_close(b.rot, a.rot, atol=1e-12, rtol=0)
    torch.testing.assert_close(b.pos, a.pos, atol=1e-12, rtol=0)
    g = torch.Generator().manual_seed(1)
    gR, gx = torch.randn(a.rot.shape, generator=g, dtype=torch.float64), torch.randn(a.pos.shape, generator=g, dtype=torch.float64)
    ((a.rot * gR).sum() + (a.pos * gx).sum()).backward()
    ((b.rot * gR).sum() + (b.pos * gx).sum()).backward()
    torch.testing.assert_close(q2.grad, q1.grad, atol=1e-10, rtol=0)
    assert torch.autograd.gradcheck(lambda q: tuple(kin.fast(q).__dict__.values()), (q[:2].clone().requires_grad_(True),))
